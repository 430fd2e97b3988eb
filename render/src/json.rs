//! Reading and writing the small JSON files of FORMATS.md (camera.json, pose.json) with serde.

use std::path::Path;

use serde::Serialize;
use serde::de::DeserializeOwned;

use crate::error::{RenderError, Result};

/// Parses a JSON file into `T`; serde's message names the missing or mistyped field and the line.
pub(crate) fn read_json<T: DeserializeOwned>(path: &Path) -> Result<T> {
    let text = std::fs::read_to_string(path).map_err(|e| RenderError::io(path, "read", e))?;
    serde_json::from_str(&text).map_err(|e| RenderError::io(path, "parse JSON", e))
}

/// Writes `value` as pretty-printed JSON.
pub(crate) fn write_json<T: Serialize>(path: &Path, value: &T) -> Result<()> {
    let text = serde_json::to_string_pretty(value).map_err(|e| RenderError::io(path, "serialise JSON", e))?;
    std::fs::write(path, text + "\n").map_err(|e| RenderError::io(path, "write", e))
}
