//! The errors a user can cause, each with its exit status.

use std::fmt;

/// A deck error: what a user typed wrong, with the file, the key and where TOML found it.
#[derive(Debug, Clone, PartialEq)]
pub struct DeckError {
    /// The deck file as the user named it.
    pub file: String,
    /// Dotted key path, e.g. `materials[0].density`.
    pub key: String,
    /// Line and column (1-based) where TOML located the problem, when it did.
    pub line_col: Option<(usize, usize)>,
    /// What is wrong, for a person.
    pub message: String,
}

impl fmt::Display for DeckError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.line_col {
            Some((l, c)) => write!(
                f,
                "{}:{}:{}: {}: {}",
                self.file, l, c, self.key, self.message
            ),
            None => write!(f, "{}: {}: {}", self.file, self.key, self.message),
        }
    }
}

impl std::error::Error for DeckError {}

/// What can stop pmpm: a bad deck, a file it cannot write, a run that blows up.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// The deck is wrong (exit status 2).
    #[error("{0}")]
    Deck(#[from] DeckError),
    /// A deck asks for something this version cannot do yet (exit status 2).
    #[error("{file}: {key}: {message}")]
    Unsupported {
        /// Deck file.
        file: String,
        /// Key that asks for it.
        key: String,
        /// What is missing.
        message: String,
    },
    /// A command-line argument or output directory is unusable (exit status 2).
    #[error("{0}")]
    Usage(String),
    /// Reading or writing a file failed (exit status 1).
    #[error("{path}: {source}")]
    Io {
        /// The file or directory.
        path: String,
        /// What the system said.
        source: std::io::Error,
    },
    /// The run blew up: NaN, or a particle left the grid (exit status 3).
    #[error("{0}")]
    BlowUp(String),
    /// The run was stopped by SIGINT (Ctrl-C) or SIGTERM after writing a checkpoint (exit
    /// status 130, as a shell reports a command stopped by Ctrl-C).
    #[error("{0}")]
    Interrupted(String),
}

impl Error {
    /// Process exit status for this error.
    pub fn exit_code(&self) -> u8 {
        match self {
            Error::Deck(_) | Error::Unsupported { .. } | Error::Usage(_) => 2,
            Error::Io { .. } => 1,
            Error::BlowUp(_) => 3,
            Error::Interrupted(_) => 130,
        }
    }

    /// An I/O error on `path`.
    pub fn io(path: impl AsRef<std::path::Path>, source: std::io::Error) -> Self {
        Error::Io {
            path: path.as_ref().display().to_string(),
            source,
        }
    }
}

impl Error {
    /// The same error with `note` added to the end of its message: a file it could not write,
    /// a blow-up or an interrupt says where the run's files stand. Other errors are returned
    /// as they are.
    pub fn with_note(self, note: &str) -> Self {
        match self {
            Error::Io { path, source } => Error::Io {
                path,
                source: std::io::Error::new(source.kind(), format!("{source}{note}")),
            },
            Error::BlowUp(m) => Error::BlowUp(m + note),
            Error::Interrupted(m) => Error::Interrupted(m + note),
            e => e,
        }
    }

    /// Names the deck file in an error raised where it was not known.
    pub fn with_file(mut self, name: &str) -> Self {
        match &mut self {
            Error::Deck(d) if d.file.is_empty() => d.file = name.to_string(),
            Error::Unsupported { file, .. } if file.is_empty() => *file = name.to_string(),
            _ => {}
        }
        self
    }
}
