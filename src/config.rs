//! Shared plumbing for the `rt-config/*.toml` files: one error type that
//! names the file, the key and the allowed range, a loader that turns TOML
//! syntax and unknown keys into that error, and range checks.
//!
//! Each configuration struct (service, device, stream) lives next to the code
//! it configures and validates itself with a [`Checker`]; scenes too
//! ([`crate::scene::SceneError`] is this error type).

use serde::de::DeserializeOwned;
use std::fmt::Display;
use std::path::{Path, PathBuf};

/// A configuration error: the file, the dotted key and what is allowed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{path}: {key}: {msg}")]
pub struct ConfigError {
    /// The file (or `<inline>`).
    pub path: PathBuf,
    /// The offending key, dotted (e.g. `loop.priority`), or `(file)` /
    /// `(syntax)`.
    pub key: String,
    /// What is wrong and what is allowed.
    pub msg: String,
}

/// Reads and deserializes a TOML file; I/O and syntax errors (including
/// unknown keys, with `#[serde(deny_unknown_fields)]`) become [`ConfigError`]s.
pub fn load_toml<T: DeserializeOwned>(path: &Path) -> Result<T, ConfigError> {
    let text = std::fs::read_to_string(path).map_err(|e| ConfigError {
        path: path.to_path_buf(),
        key: "(file)".into(),
        msg: e.to_string(),
    })?;
    parse_toml(&text, path)
}

/// Deserializes TOML text; `path` is used in messages. A syntax error is
/// reported as `(syntax)` with its line and column; a value of the wrong
/// type, a bad choice or an unknown key is reported at its dotted key
/// (an unknown key is named itself), also with its line and column.
pub fn parse_toml<T: DeserializeOwned>(text: &str, path: &Path) -> Result<T, ConfigError> {
    let err = |key: String, e: &toml::de::Error| ConfigError {
        path: path.to_path_buf(),
        key,
        msg: match e.span() {
            Some(span) => {
                let (line, col) = line_col(text, span.start);
                format!("line {line}, column {col}: {}", e.message().trim())
            }
            None => e.message().trim().to_string(),
        },
    };
    let de = toml::Deserializer::parse(text).map_err(|e| err("(syntax)".into(), &e))?;
    serde_path_to_error::deserialize(de).map_err(|e| {
        let key = e.path().to_string();
        let key = if key == "." { "(top level)".to_string() } else { key };
        err(key, e.inner())
    })
}

/// 1-based line and column (in characters) of byte offset `at` in `text`.
fn line_col(text: &str, at: usize) -> (usize, usize) {
    let at = at.min(text.len());
    let before = text.get(..at).unwrap_or(text);
    let line = before.matches('\n').count() + 1;
    let col = before.rsplit('\n').next().map(|l| l.chars().count()).unwrap_or(0) + 1;
    (line, col)
}

/// Range checks that produce [`ConfigError`]s naming one file.
#[derive(Debug, Clone)]
pub struct Checker {
    path: PathBuf,
}

impl Checker {
    /// Checks for the file at `path`.
    pub fn new(path: &Path) -> Checker {
        Checker {
            path: path.to_path_buf(),
        }
    }

    /// An error at `key`.
    pub fn err(&self, key: &str, msg: impl Into<String>) -> ConfigError {
        ConfigError {
            path: self.path.clone(),
            key: key.into(),
            msg: msg.into(),
        }
    }

    /// `value` must be finite and in `[lo, hi]`; `unit` is printed after the
    /// range (e.g. "N", "s", "" for none).
    pub fn f64_in(&self, key: &str, value: f64, lo: f64, hi: f64, unit: &str) -> Result<(), ConfigError> {
        if value.is_finite() && (lo..=hi).contains(&value) {
            Ok(())
        } else {
            Err(self.err(
                key,
                format!("{value}: must be in [{lo}, {hi}] {unit}")
                    .trim_end()
                    .to_string(),
            ))
        }
    }

    /// An integer `value` must be in `[lo, hi]`.
    pub fn int_in<T: PartialOrd + Display + Copy>(&self, key: &str, value: T, lo: T, hi: T) -> Result<(), ConfigError> {
        if lo <= value && value <= hi {
            Ok(())
        } else {
            Err(self.err(key, format!("{value}: must be in {lo}..={hi}")))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug, serde::Deserialize)]
    #[serde(deny_unknown_fields)]
    #[allow(dead_code)]
    struct Small {
        rate_hz: f64,
    }

    #[test]
    fn errors_name_the_file_the_key_and_the_range() {
        let p = Path::new("rt-config/x.toml");
        let e = parse_toml::<Small>("rate_hz = 1.0\nbogus = 2", p).unwrap_err();
        assert_eq!(
            e.key, "bogus",
            "an unknown key is named, not called a syntax error: {e}"
        );
        assert!(e.msg.contains("bogus") && e.msg.starts_with("line 2, column 1:"), "{e}");
        assert!(
            !e.msg.contains('^') && !e.msg.contains('|'),
            "no caret drawing on one line: {e}"
        );
        let e = parse_toml::<Small>("rate_hz = \"fast\"", p).unwrap_err();
        assert_eq!(e.key, "rate_hz", "{e}");
        assert!(e.msg.starts_with("line 1, column 11:"), "{e}");
        let e = parse_toml::<Small>("rate_hz = = 1", p).unwrap_err();
        assert_eq!(e.key, "(syntax)", "{e}");
        assert!(e.msg.starts_with("line 1,"), "{e}");
        let c = Checker::new(p);
        let e = c.f64_in("loop.rate_hz", f64::NAN, 1.0, 2.0, "Hz").unwrap_err();
        assert_eq!(
            e.to_string(),
            "rt-config/x.toml: loop.rate_hz: NaN: must be in [1, 2] Hz"
        );
        assert!(c.int_in("ring.pose", 0usize, 2, 4096).is_err());
        assert!(c.int_in("ring.pose", 8usize, 2, 4096).is_ok());
        let e = load_toml::<Small>(Path::new("/nonexistent/x.toml")).unwrap_err();
        assert_eq!(e.key, "(file)");
    }
}
