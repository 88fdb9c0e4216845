//! The report's prose: one markdown file per case under `validation/prose/`, compiled in, so
//! that the binary needs no files at run time.
//!
//! A file is `# NAME` (the case's registry name), then the sections `## title`, `## setup`,
//! `## metric` and `## bound`, one paragraph each, in that order, and optionally `## notes`
//! with one `### KEY` per note, one paragraph each. A paragraph's lines are joined with single
//! spaces. `{name}` (lower-case letters, digits, `_`) is a placeholder the code fills; a brace
//! that is not part of one is an error. Filling is strict: a placeholder the code does not fill,
//! or a value the text has no placeholder for, panics (the case is then reported as failed),
//! and the unit test below runs every fill the cases make, in both modes.
//!
//! The files hold what does not depend on a run. Observations from development runs (figures
//! measured by hand, experiments tried and not kept) are in `docs/validation-notes.md`, not here.

use super::Section;
use std::fmt::Display;

/// Values for placeholders: `(name, value)`.
pub(crate) type Vars<'a> = &'a [(&'a str, &'a dyn Display)];

/// The header sections every file has, in order.
const HEADER: [&str; 4] = ["title", "setup", "metric", "bound"];

/// The compiled-in text of `validation/prose/CASE.md`, if there is one.
fn source(case: &str) -> Option<&'static str> {
    macro_rules! prose {
        ($($n:literal),*) => {
            match case {
                $($n => Some(include_str!(concat!(env!("CARGO_MANIFEST_DIR"), "/validation/prose/", $n, ".md"))),)*
                _ => None,
            }
        };
    }
    prose!(
        "hydrostatic",
        "martin_moyce",
        "conservation",
        "lobovsky",
        "cavity",
        "poiseuille",
        "couette",
        "taylor_green",
        "bingham_poiseuille",
        "strip_footing",
        "elastic"
    )
}

/// A parsed prose file: the header sections in order, then the notes, as (key, paragraph).
#[derive(Debug)]
struct Doc {
    header: Vec<(String, String)>,
    notes: Vec<(String, String)>,
}

/// Splits a prose file (module comment). Errors name the case and the line.
fn parse(case: &str, text: &str) -> Result<Doc, String> {
    // (level, key, paragraphs) of each heading, in order
    let mut blocks: Vec<(usize, String, Vec<String>)> = Vec::new();
    let mut para: Option<String> = None;
    let close = |para: &mut Option<String>, blocks: &mut Vec<(usize, String, Vec<String>)>| {
        if let Some(p) = para.take() {
            if let Some(b) = blocks.last_mut() {
                b.2.push(p);
            }
        }
    };
    for (i, raw) in text.lines().enumerate() {
        let line = raw.trim();
        let at = |m: &str| format!("validation/prose/{case}.md, line {}: {m}", i + 1);
        if line.is_empty() {
            close(&mut para, &mut blocks);
        } else if line.starts_with('#') {
            close(&mut para, &mut blocks);
            let level = line.chars().take_while(|&c| c == '#').count();
            let key = line[level..].trim();
            if !(1..=3).contains(&level) || key.is_empty() {
                return Err(at(&format!("not a heading this file can have: {line:?}")));
            }
            blocks.push((level, key.to_string(), Vec::new()));
        } else if blocks.is_empty() {
            return Err(at("text before the `# NAME` heading"));
        } else {
            let p = para.get_or_insert_with(String::new);
            if !p.is_empty() {
                p.push(' ');
            }
            p.push_str(line);
        }
    }
    close(&mut para, &mut blocks);
    let err = |m: String| format!("validation/prose/{case}.md: {m}");
    let mut blocks = blocks.into_iter();
    match blocks.next() {
        Some((1, name, paras)) if name == case && paras.is_empty() => {}
        Some((1, name, _)) if name != case => {
            return Err(err(format!(
                "the first heading names {name:?}, not {case:?}"
            )))
        }
        _ => {
            return Err(err(format!(
                "must start with `# {case}` and no text under it"
            )))
        }
    }
    let one = |key: &str, paras: Vec<String>| -> Result<String, String> {
        let mut paras = paras.into_iter();
        match (paras.next(), paras.next()) {
            (Some(p), None) => {
                placeholders(&p).map_err(|e| err(format!("{key}: {e}")))?;
                Ok(p)
            }
            (None, _) => Err(err(format!("{key} is empty"))),
            (Some(_), Some(_)) => Err(err(format!(
                "{key} has more than one paragraph (one note per `### KEY`)"
            ))),
        }
    };
    let mut doc = Doc {
        header: Vec::new(),
        notes: Vec::new(),
    };
    let mut in_notes = false;
    for (level, key, paras) in blocks {
        match level {
            2 if key == "notes" && doc.header.len() == HEADER.len() && !in_notes => {
                if !paras.is_empty() {
                    return Err(err("text under `## notes` outside a `### KEY`".into()));
                }
                in_notes = true;
            }
            2 if !in_notes && HEADER.get(doc.header.len()) == Some(&key.as_str()) => {
                let text = one(&key, paras)?;
                doc.header.push((key, text));
            }
            2 => {
                return Err(err(format!(
                    "unexpected `## {key}`: the sections are {} and then `notes`, in that order, once each",
                    HEADER.join(", ")
                )))
            }
            3 if in_notes => {
                if !is_name(&key) {
                    return Err(err(format!(
                        "note key {key:?}: lower-case letters, digits and _"
                    )));
                }
                if doc.notes.iter().any(|n| n.0 == key) {
                    return Err(err(format!("note {key:?} twice")));
                }
                let text = one(&format!("note {key}"), paras)?;
                doc.notes.push((key, text));
            }
            _ => return Err(err(format!("unexpected heading {key:?} at level {level}"))),
        }
    }
    if doc.header.len() < HEADER.len() {
        return Err(err(format!("missing `## {}`", HEADER[doc.header.len()])));
    }
    Ok(doc)
}

fn is_name(s: &str) -> bool {
    s.starts_with(|c: char| c.is_ascii_lowercase())
        && s.chars()
            .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '_')
}

/// The placeholders of `text`, in order (repeats kept); an error for a brace outside one.
fn placeholders(text: &str) -> Result<Vec<&str>, String> {
    let mut out = Vec::new();
    let mut rest = text;
    while let Some(k) = rest.find(['{', '}']) {
        if rest[k..].starts_with('}') {
            return Err(format!("a '}}' with no '{{' before it: {:?}", &rest[..=k]));
        }
        let after = &rest[k + 1..];
        let end = after
            .find('}')
            .ok_or_else(|| format!("a '{{' with no '}}' after it: {:?}", &rest[k..]))?;
        let name = &after[..end];
        if !is_name(name) {
            return Err(format!(
                "{{{name}}} is not a placeholder (lower-case letters, digits and _)"
            ));
        }
        out.push(name);
        rest = &after[end + 1..];
    }
    Ok(out)
}

/// `text` with its placeholders replaced by `vars`; an error for a placeholder with no value
/// and for a value the text does not use.
fn fill(text: &str, vars: Vars) -> Result<String, String> {
    let names = placeholders(text)?;
    if let Some(n) = names.iter().find(|n| !vars.iter().any(|v| v.0 == **n)) {
        return Err(format!("the code does not fill {{{n}}}"));
    }
    if let Some(v) = vars.iter().find(|v| !names.contains(&v.0)) {
        return Err(format!("the text has no {{{}}} for the code's value", v.0));
    }
    let mut out = String::with_capacity(text.len());
    let mut rest = text;
    while let Some(k) = rest.find('{') {
        out.push_str(&rest[..k]);
        let end = k + rest[k..].find('}').expect("checked by placeholders");
        let name = &rest[k + 1..end];
        let value = vars.iter().find(|v| v.0 == name).expect("checked above").1;
        out.push_str(&value.to_string());
        rest = &rest[end + 1..];
    }
    out.push_str(rest);
    Ok(out)
}

fn doc(case: &str) -> Doc {
    let text = source(case).unwrap_or_else(|| panic!("no file validation/prose/{case}.md"));
    parse(case, text).unwrap_or_else(|e| panic!("{e}"))
}

/// A section of `case` with its title, set-up, metric and bound from the prose file,
/// placeholders filled from `vars`: each placeholder must have a value and each value must be
/// used by one of the four (panics otherwise).
pub(crate) fn section(case: &str, vars: Vars) -> Section {
    let d = doc(case);
    let mut used = vec![false; vars.len()];
    let mut texts = Vec::new();
    for (key, text) in &d.header {
        let names = placeholders(text).expect("checked by parse");
        let mine: Vec<(&str, &dyn Display)> = vars
            .iter()
            .enumerate()
            .filter(|(_, v)| names.contains(&v.0))
            .map(|(i, v)| {
                used[i] = true;
                *v
            })
            .collect();
        texts.push(
            fill(text, &mine).unwrap_or_else(|e| panic!("validation/prose/{case}.md, {key}: {e}")),
        );
        #[cfg(test)]
        tests::mark_used(case, key);
    }
    if let Some(k) = used.iter().position(|u| !u) {
        panic!(
            "validation/prose/{case}.md: no {{{}}} in its title, setup, metric or bound for the code's value",
            vars[k].0
        );
    }
    let mut texts = texts.into_iter();
    let mut next = || texts.next().expect("four header sections");
    Section {
        title: next(),
        setup: next(),
        metric: next(),
        bound: next(),
        ..Default::default()
    }
}

/// The note `key` of `case`, placeholders filled from `vars` (strictly, as [`section`]).
pub(crate) fn note(case: &str, key: &str, vars: Vars) -> String {
    let d = doc(case);
    let text = d
        .notes
        .iter()
        .find(|n| n.0 == key)
        .unwrap_or_else(|| panic!("validation/prose/{case}.md has no note {key:?}"));
    #[cfg(test)]
    tests::mark_used(case, &format!("note {key}"));
    fill(&text.1, vars).unwrap_or_else(|e| panic!("validation/prose/{case}.md, note {key}: {e}"))
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use std::cell::RefCell;
    use std::collections::BTreeSet;

    thread_local! {
        /// (case, part) of every text the code filled on this thread.
        static USED: RefCell<BTreeSet<(String, String)>> = const { RefCell::new(BTreeSet::new()) };
    }

    pub(crate) fn mark_used(case: &str, part: &str) {
        USED.with(|u| u.borrow_mut().insert((case.to_string(), part.to_string())));
    }

    #[test]
    fn placeholders_are_filled_strictly() {
        let v = 0.5;
        let vars: Vars = &[("end", &v), ("quick", &"")];
        assert_eq!(
            fill("to t = {end} s{quick}.", vars).unwrap(),
            "to t = 0.5 s."
        );
        assert!(fill("to t = {end} s.", vars)
            .unwrap_err()
            .contains("no {quick}"));
        assert!(fill("to t = {end} s{quick} at {h}.", vars)
            .unwrap_err()
            .contains("does not fill {h}"));
        assert!(placeholders("a {B} b").is_err());
        assert!(placeholders("a { b").is_err());
        assert!(placeholders("a } b").is_err());
        assert_eq!(
            placeholders("{a} and {b_2} and {a}").unwrap(),
            ["a", "b_2", "a"]
        );
    }

    #[test]
    fn a_file_needs_its_headings_in_order() {
        let good = "# c\n\n## title\n\nT\n\n## setup\n\nS one\nS two\n\n## metric\n\nM\n\n## bound\n\nB\n\n## notes\n\n### a_1\n\nN {x}\n";
        let d = parse("c", good).unwrap();
        assert_eq!(d.header[1], ("setup".into(), "S one S two".into()));
        assert_eq!(d.notes, [("a_1".into(), "N {x}".into())]);
        for (bad, why) in [
            (good.replace("# c\n", "# d\n"), "names \"d\""),
            (
                good.replace("## metric\n\nM\n\n", ""),
                "unexpected `## bound`",
            ),
            (
                good.replace("## bound\n\nB\n\n", ""),
                "unexpected `## notes`",
            ),
            (good.replace("\n## notes\n\n### a_1\n\nN {x}\n", ""), ""),
            (
                good.replace("\n\nB\n", "\n\nB\n\nB2\n"),
                "more than one paragraph",
            ),
            (
                good.replace("### a_1\n\nN {x}\n", "### a_1\n\n"),
                "note a_1 is empty",
            ),
            (good.replace("N {x}", "N {X}"), "not a placeholder"),
            (good.replace("### a_1", "### A"), "note key"),
            (
                good.replace("## title\n\nT", "## title\n\nT\n\n#### x"),
                "heading",
            ),
            (format!("intro\n{good}"), "before the `# NAME`"),
        ] {
            match parse("c", &bad) {
                Ok(_) if why.is_empty() => {}
                Ok(_) => panic!("accepted, expected {why:?}:\n{bad}"),
                Err(e) => assert!(!why.is_empty() && e.contains(why), "{e}, expected {why:?}"),
            }
        }
        let no_bound = good.split("## bound").next().unwrap();
        assert!(parse("c", no_bound)
            .unwrap_err()
            .contains("missing `## bound`"));
    }

    /// Every case has a file and every file is a case's; each parses; the code's fills of every
    /// case, in full and in quick mode, fill every placeholder and leave none; and every section
    /// and note of every file is used by the code.
    #[test]
    fn every_prose_file_parses_and_the_code_fills_all_of_it() {
        let mut files = super::super::file_stems("validation/prose", "md");
        files.retain(|f| f != "README");
        let mut cases: Vec<String> = super::super::case_names()
            .into_iter()
            .map(String::from)
            .collect();
        cases.sort();
        assert_eq!(
            files, cases,
            "validation/prose/*.md against the registered cases"
        );
        let mut parts = BTreeSet::new();
        for case in &cases {
            let text = source(case).unwrap_or_else(|| panic!("{case} is not compiled in"));
            let d = parse(case, text).unwrap_or_else(|e| panic!("{e}"));
            for (key, _) in &d.header {
                parts.insert((case.clone(), key.clone()));
            }
            for (key, _) in &d.notes {
                parts.insert((case.clone(), format!("note {key}")));
            }
        }
        for quick in [false, true] {
            for text in super::super::prose_texts(quick) {
                assert!(!text.trim().is_empty());
                assert!(
                    !text.contains(['{', '}']),
                    "a brace is left in the filled text: {text}"
                );
            }
        }
        let used = USED.with(|u| u.borrow().clone());
        let unused: Vec<_> = parts.difference(&used).collect();
        assert!(unused.is_empty(), "never filled by the code: {unused:?}");
        let unknown: Vec<_> = used.difference(&parts).collect();
        assert!(unknown.is_empty(), "filled but not in a file: {unknown:?}");
    }
}
