//! The crate's one error type: every message names the file or the field and
//! the rule broken, or the phase whose solver refused.

use std::fmt;

use optim::OptimError;
use render::RenderError;

/// Shorthand for results whose error is an [`Error`].
pub type Result<T> = std::result::Result<T, Error>;

/// What went wrong, in words a user can act on.
#[derive(Debug)]
pub enum Error {
    /// A file or value that breaks a rule of the formats, or that could not
    /// be read or written (the renderer's error: file, field, rule).
    Format(RenderError),
    /// An input or setting that breaks a rule of the method's, e.g. a mask
    /// too small to estimate from or a map that is not 2:1.
    Invalid {
        /// What broke the rule (a field, a flag, a phase's input).
        field: String,
        /// The rule, in words.
        rule: String,
    },
    /// A solver refused its settings or inputs.
    Solver {
        /// The phase whose solver it was.
        phase: String,
        /// The solver's own error.
        source: OptimError,
    },
}

impl Error {
    /// `field` breaks `rule`.
    pub fn invalid(field: impl Into<String>, rule: impl Into<String>) -> Self {
        Error::Invalid {
            field: field.into(),
            rule: rule.into(),
        }
    }

    /// The solver of `phase` refused: `source`.
    pub fn solver(phase: impl Into<String>) -> impl FnOnce(OptimError) -> Self {
        let phase = phase.into();
        move |source| Error::Solver { phase, source }
    }
}

impl Error {
    /// Names the file this error belongs to, when it was raised while
    /// validating values read from it.
    pub fn in_file(self, path: impl AsRef<std::path::Path>) -> Self {
        match self {
            Error::Format(e) => Error::Format(e.in_file(path)),
            Error::Invalid { field, rule } => Error::Format(RenderError::field(path, field, rule)),
            solver => solver,
        }
    }

    /// The field the error is about, if any.
    pub fn field_name(&self) -> Option<&str> {
        match self {
            Error::Format(e) => e.field_name(),
            Error::Invalid { field, .. } => Some(field),
            Error::Solver { .. } => None,
        }
    }

    /// The rule that was broken, in words.
    pub fn rule(&self) -> String {
        match self {
            Error::Format(e) => e.rule().to_string(),
            Error::Invalid { rule, .. } => rule.clone(),
            Error::Solver { source, .. } => source.to_string(),
        }
    }
}

impl From<RenderError> for Error {
    fn from(e: RenderError) -> Self {
        Error::Format(e)
    }
}

impl fmt::Display for Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Error::Format(e) => e.fmt(f),
            Error::Invalid { field, rule } => write!(f, "field `{field}`: {rule}"),
            Error::Solver { phase, source } => write!(f, "{phase}: {source}"),
        }
    }
}

impl std::error::Error for Error {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            Error::Format(e) => Some(e),
            Error::Invalid { .. } => None,
            Error::Solver { source, .. } => Some(source),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn messages_name_the_field_or_file_and_the_rule() {
        let e = Error::invalid("env size", "100x30 is not a 2:1 map");
        assert_eq!(e.to_string(), "field `env size`: 100x30 is not a 2:1 map");
        let e = Error::from(RenderError::field(
            "probe.json",
            "roughness",
            "value 1.7 outside [0, 1]",
        ));
        assert_eq!(e.to_string(), "probe.json: field `roughness`: value 1.7 outside [0, 1]");
        let refused = OptimError::WrongLength {
            field: "x0",
            expected: 3,
            actual: 2,
        };
        let e = Error::solver("lighting solve")(refused);
        assert_eq!(e.to_string(), "lighting solve: optim: `x0` has length 2, expected 3");
    }
}
