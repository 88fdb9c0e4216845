//! `[about]`: what a deck models, in the user's words: a title, the experiment or solution it
//! reproduces, who wrote it. The run keeps it in run.toml with the rest of the deck, and
//! `pmpm check` shows it, so that a directory of runs says what each one is.

use crate::error::DeckError;
use crate::keys::Check;
use serde::{Deserialize, Serialize};

/// The longest text a key of `[about]` takes (characters): a paragraph, not a file.
const MAX_TEXT: usize = 4000;

/// `[about]`: the deck's title and where it comes from. Nothing in it changes the run.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AboutDeck {
    /// One line naming the case ("Martin & Moyce dam break, n^2 = 2").
    pub title: String,
    /// What the deck models and how, in a few sentences.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub description: Option<String>,
    /// The experiment, paper or exact solution it is compared with (a citation, a DOI).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reference: Option<String>,
    /// Who wrote the deck.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub author: Option<String>,
}

impl AboutDeck {
    /// The section, if given: a title of one line, and texts that print (no control
    /// characters but the description's line breaks), each at most [`MAX_TEXT`] characters.
    pub(crate) fn check(about: &Option<AboutDeck>, c: &Check) -> Result<(), DeckError> {
        let Some(a) = about else { return Ok(()) };
        if a.title.trim().is_empty() {
            return Err(c.err("about.title", "must not be empty"));
        }
        let texts = [
            ("title", Some(&a.title), false),
            ("description", a.description.as_ref(), true),
            ("reference", a.reference.as_ref(), false),
            ("author", a.author.as_ref(), false),
        ];
        for (key, text, lines) in texts {
            let Some(text) = text else { continue };
            let n = text.chars().count();
            if n > MAX_TEXT {
                return Err(c.err(
                    format!("about.{key}"),
                    format!("is {n} characters long, more than {MAX_TEXT}"),
                ));
            }
            if let Some(ch) = text
                .chars()
                .find(|&ch| ch.is_control() && !(lines && matches!(ch, '\n' | '\t')))
            {
                return Err(c.err(
                    format!("about.{key}"),
                    format!(
                        "holds the control character {ch:?}{}",
                        if lines {
                            ""
                        } else {
                            ": it is one line (a description may have several)"
                        }
                    ),
                ));
            }
        }
        Ok(())
    }

    /// One line for `pmpm check`: the title, and the reference in brackets.
    pub fn describe(&self) -> String {
        match &self.reference {
            Some(r) => format!("{} [{r}]", self.title),
            None => self.title.clone(),
        }
    }
}

#[cfg(test)]
mod tests {
    use crate::deck::Deck;

    /// A small valid deck with `about` as its `[about]` table.
    fn deck(about: &str) -> Result<Deck, crate::error::DeckError> {
        let text = format!(
            r#"
{about}
[simulation]
dimension = 2
end_time = 0.01
gravity = [0.0, -9.81]

[grid]
origin = [0.0, 0.0]
size = [0.2, 0.2]
cell_size = 0.02

[[materials]]
name = "water"
density = 1000.0

[[bodies]]
material = "water"
shape = {{ type = "box", min = [0.0, 0.0], max = [0.1, 0.1] }}
"#
        );
        let mut deck = Deck::parse(&text, "t.toml")?;
        deck.validate("t.toml")?;
        Ok(deck)
    }

    #[test]
    fn the_about_table_is_optional_and_kept_in_run_toml() {
        let plain = deck("").unwrap();
        assert_eq!(plain.about, None);
        let text = plain.to_run_toml();
        assert!(
            text.contains("[simulation]") && !text.contains("about"),
            "{text}"
        );
        let given = deck(
            "[about]\ntitle = \"Column\"\ndescription = \"A column.\\nAt rest.\"\nreference = \"doi:10/x\"",
        )
        .unwrap();
        let about = given.about.as_ref().unwrap();
        assert_eq!(about.describe(), "Column [doi:10/x]");
        let again = Deck::parse(&given.to_run_toml(), "run.toml").unwrap();
        assert_eq!(again.about, given.about);
    }

    #[test]
    fn a_bad_about_table_names_its_key() {
        for (table, key, words) in [
            ("title = \" \"", "about.title", "must not be empty"),
            ("title = \"a\\nb\"", "about.title", "it is one line"),
            (
                "title = \"a\"\nauthor = \"x\\u0007\"",
                "about.author",
                "control character",
            ),
        ] {
            let e = deck(&format!("[about]\n{table}")).unwrap_err();
            assert_eq!(e.key, key, "{table}");
            assert!(e.message.contains(words), "{table}: {}", e.message);
        }
        let e = deck("[about]\nauthor = \"me\"").unwrap_err();
        assert_eq!(e.key, "about.title");
        assert!(e.message.contains("required"), "{}", e.message);
        let long = "x".repeat(super::MAX_TEXT + 1);
        let e = deck(&format!("[about]\ntitle = \"{long}\"")).unwrap_err();
        assert!(e.message.contains("characters long"), "{}", e.message);
    }
}
