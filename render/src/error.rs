//! The one error type of the crate: every message names the file, the field and the rule broken.

use std::fmt;
use std::path::{Path, PathBuf};

/// Shorthand for results whose error is a [`RenderError`].
pub type Result<T> = std::result::Result<T, RenderError>;

/// A file (or an in-memory value) that breaks a rule of FORMATS.md, or that could not be read or written.
///
/// Displayed as `file: field `name`: rule`, e.g.
/// "probe.json: field `roughness`: value 1.7 outside [0, 1]"; the parts that are unknown are left out.
#[derive(Debug)]
pub struct RenderError {
    path: Option<PathBuf>,
    field: Option<String>,
    rule: String,
    source: Option<Box<dyn std::error::Error + Send + Sync>>,
}

impl RenderError {
    /// A rule broken by a whole file (size, format, channels).
    pub fn file(path: impl AsRef<Path>, rule: impl Into<String>) -> Self {
        Self {
            path: Some(path.as_ref().to_path_buf()),
            field: None,
            rule: rule.into(),
            source: None,
        }
    }

    /// A rule broken by one field of a file.
    pub fn field(path: impl AsRef<Path>, field: impl Into<String>, rule: impl Into<String>) -> Self {
        Self::file(path, rule).with_field(field)
    }

    /// A rule broken by a value that does not (yet) come from a file, e.g. `Camera::new` arguments.
    pub fn value(field: impl Into<String>, rule: impl Into<String>) -> Self {
        Self {
            path: None,
            field: Some(field.into()),
            rule: rule.into(),
            source: None,
        }
    }

    /// A file that could not be opened, parsed or written; the underlying error is kept as the source.
    pub fn io(path: impl AsRef<Path>, action: &str, source: impl std::error::Error + Send + Sync + 'static) -> Self {
        let rule = format!("cannot {action}: {source}");
        Self {
            source: Some(Box::new(source)),
            ..Self::file(path, rule)
        }
    }

    /// Names the file this error belongs to, when it was raised while validating values read from it.
    pub fn in_file(mut self, path: impl AsRef<Path>) -> Self {
        self.path.get_or_insert_with(|| path.as_ref().to_path_buf());
        self
    }

    /// Names the field this error belongs to, unless it already names one.
    pub fn with_field(mut self, field: impl Into<String>) -> Self {
        self.field.get_or_insert_with(|| field.into());
        self
    }

    /// The file the error is about, if known.
    pub fn path(&self) -> Option<&Path> {
        self.path.as_deref()
    }

    /// The field the error is about, if any.
    pub fn field_name(&self) -> Option<&str> {
        self.field.as_deref()
    }

    /// The rule that was broken, in words.
    pub fn rule(&self) -> &str {
        &self.rule
    }
}

impl fmt::Display for RenderError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if let Some(path) = &self.path {
            write!(f, "{}: ", path.display())?;
        }
        if let Some(field) = &self.field {
            write!(f, "field `{field}`: ")?;
        }
        f.write_str(&self.rule)
    }
}

impl std::error::Error for RenderError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        self.source.as_deref().map(|e| e as &(dyn std::error::Error + 'static))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn message_names_file_field_and_rule() {
        let e = RenderError::field("probe.json", "roughness", "value 1.7 outside [0, 1]");
        assert_eq!(e.to_string(), "probe.json: field `roughness`: value 1.7 outside [0, 1]");
        let e = RenderError::file("env.exr", "width 300 is not 2 x height 128");
        assert_eq!(e.to_string(), "env.exr: width 300 is not 2 x height 128");
        let e = RenderError::value("fov_y_deg", "value 190 outside (0, 180)").in_file("camera.json");
        assert_eq!(
            e.to_string(),
            "camera.json: field `fov_y_deg`: value 190 outside (0, 180)"
        );
    }
}
