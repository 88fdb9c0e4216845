//! The one reader of the numeric CSV files the application reads: pmpm's own `series.csv`,
//! `probes.csv` and `rigid_bodies.csv` (for `plot`), and the reference tables of the
//! validation suite. `#` lines (a reference table's source) and blank lines are skipped; the
//! first other line is the header; every row holds one number per header column.

/// A numeric CSV table: its column names and its rows.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Table {
    /// Column names, trimmed.
    pub header: Vec<String>,
    /// One number per column in each row.
    pub rows: Vec<Vec<f64>>,
}

impl Table {
    /// Parses `text`; on a row that is not one number per column, the error names the line
    /// (counted from 1 in the file) and what was expected.
    pub fn parse(text: &str) -> Result<Self, String> {
        let mut lines = text
            .lines()
            .enumerate()
            .filter(|(_, l)| !l.starts_with('#') && !l.trim().is_empty());
        let header: Vec<String> = match lines.next() {
            Some((_, l)) => l.split(',').map(|s| s.trim().to_string()).collect(),
            None => Vec::new(),
        };
        let mut rows = Vec::new();
        for (i, line) in lines {
            let row = line
                .split(',')
                .map(|s| s.trim().parse::<f64>())
                .collect::<Result<Vec<f64>, _>>()
                .ok()
                .filter(|r| r.len() == header.len())
                .ok_or_else(|| {
                    format!(
                        "line {}: expected {} numbers ({})",
                        i + 1,
                        header.len(),
                        header.join(",")
                    )
                })?;
            rows.push(row);
        }
        Ok(Self { header, rows })
    }

    /// The place of the column `name` in each row (None without such a column).
    pub fn index(&self, name: &str) -> Option<usize> {
        self.header.iter().position(|h| h == name)
    }

    /// The values of the column `name`, one per row (None without such a column).
    pub fn column(&self, name: &str) -> Option<Vec<f64>> {
        let k = self.index(name)?;
        Some(self.rows.iter().map(|r| r[k]).collect())
    }

    /// Reads and parses the file at `path`; errors name the file.
    pub fn read(path: &std::path::Path) -> Result<Self, String> {
        let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
        Self::parse(&text).map_err(|e| format!("{}: {e}", path.display()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn skips_source_lines_and_refuses_a_short_row() {
        let t = Table::parse("# source\n\nx, y\n1, 2\n3,4\n").unwrap();
        assert_eq!(t.header, ["x", "y"]);
        assert_eq!(t.rows, [[1.0, 2.0], [3.0, 4.0]]);
        let e = Table::parse("x,y\n1,2\n3\n").unwrap_err();
        assert!(e.starts_with("line 3: expected 2 numbers (x,y)"), "{e}");
    }
}
