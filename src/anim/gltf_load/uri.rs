//! Turning a glTF buffer URI into bytes without ever reading outside the asset's directory.
//!
//! A URI is either a base64 `data:` URI or a relative path, percent-decoded, under the directory of the
//! `.gltf`/`.glb` file. Everything else is an [`Error::Gltf`] naming the URI: other schemes (`file:`,
//! `http:`, …), absolute paths in any spelling (`/x`, `C:\x`, `C:x`, `\x`, `\\server\share`), any `..`
//! component (also percent-encoded or behind a backslash), Windows device names (`CON`, `NUL`, `COM1`, …),
//! colons and control characters. The check is textual and costs one pass over the URI; symbolic links
//! inside the directory are followed like any file there.

use crate::{Error, Result};
use base64::Engine;
use std::path::{Path, PathBuf};

/// The bytes `uri` names: the payload of a base64 data URI, or the file it names under `dir` (relative URIs
/// are an error without one). `what` names the referring element in messages (`buffer 2`).
pub(super) fn read_uri(uri: &str, dir: Option<&Path>, what: &str) -> Result<Vec<u8>> {
    let bad = |why: &str| Error::Gltf(format!("{what}: URI {uri:?} {why}"));
    if let Some(scheme) = scheme(uri) {
        if !scheme.eq_ignore_ascii_case("data") {
            return Err(bad(if scheme.len() == 1 {
                "starts with a drive letter; only relative paths are allowed"
            } else {
                "has a scheme other than data:; only relative paths are allowed"
            }));
        }
        let payload = uri
            .split_once(";base64,")
            .map(|(_, p)| p)
            .ok_or_else(|| bad("is a data URI that is not base64"))?;
        return base64::engine::general_purpose::STANDARD
            .decode(payload)
            .map_err(|e| bad(&format!("has bad base64: {e}")));
    }
    let relative = relative_path(uri).map_err(bad)?;
    let dir = dir.ok_or_else(|| bad("refers to a file, but no directory was given"))?;
    let path = dir.join(relative);
    std::fs::read(&path).map_err(|e| Error::Io {
        path: path.display().to_string(),
        message: e.to_string(),
    })
}

/// The URI's scheme (RFC 3986: a letter, then letters, digits, `+`, `-` or `.`, before the first `:`).
fn scheme(uri: &str) -> Option<&str> {
    let (scheme, _) = uri.split_once(':')?;
    let mut chars = scheme.chars();
    let first = chars.next()?;
    (first.is_ascii_alphabetic()
        && chars.all(|c| c.is_ascii_alphanumeric() || matches!(c, '+' | '-' | '.')))
    .then_some(scheme)
}

/// The path a scheme-less URI names, relative and free of `..`, or why it is refused. The query and
/// fragment (from the first `?` or `#`) are not part of the path; `/` and `\` both separate components.
fn relative_path(uri: &str) -> std::result::Result<PathBuf, &'static str> {
    let raw = uri.split(['?', '#']).next().unwrap_or_default();
    let decoded = percent_decode(raw)?;
    if decoded.starts_with(['/', '\\']) {
        return Err("is an absolute path; only relative paths are allowed");
    }
    if decoded.contains(':') {
        return Err("holds a colon (a drive, scheme or stream) after decoding");
    }
    if decoded.chars().any(char::is_control) {
        return Err("holds a control character after decoding");
    }
    let mut path = PathBuf::new();
    for part in decoded.split(['/', '\\']) {
        if part.is_empty() || part == "." {
            continue;
        }
        // Windows drops trailing dots and spaces from a component, so `.. ` and `...` may name the parent.
        if part.contains("..") && part.chars().all(|c| c == '.' || c == ' ') {
            return Err("has a `..` component; only paths under the asset's directory are allowed");
        }
        if is_device_name(part) {
            return Err("names a Windows device");
        }
        path.push(part);
    }
    if path.as_os_str().is_empty() {
        return Err("names no file");
    }
    Ok(path)
}

/// Whether a path component is a reserved Windows device (`CON`, `AUX`, `COM1`, …, with any extension),
/// which opens the device rather than a file there.
fn is_device_name(part: &str) -> bool {
    let stem = part.split('.').next().unwrap_or_default().trim_end();
    let upper = stem.to_ascii_uppercase();
    matches!(
        upper.as_str(),
        "CON" | "PRN" | "AUX" | "NUL" | "CONIN$" | "CONOUT$"
    ) || (upper.len() == 4
        && (upper.starts_with("COM") || upper.starts_with("LPT"))
        && upper.as_bytes()[3].is_ascii_digit())
}

/// `%XX` escapes replaced by their bytes; the result must be UTF-8.
fn percent_decode(s: &str) -> std::result::Result<String, &'static str> {
    let mut out = Vec::with_capacity(s.len());
    let mut bytes = s.bytes();
    while let Some(b) = bytes.next() {
        if b != b'%' {
            out.push(b);
            continue;
        }
        let hex = |b: Option<u8>| b.and_then(|b| (b as char).to_digit(16));
        match (hex(bytes.next()), hex(bytes.next())) {
            (Some(hi), Some(lo)) => out.push((hi * 16 + lo) as u8),
            _ => return Err("has a `%` not followed by two hex digits"),
        }
    }
    String::from_utf8(out).map_err(|_| "is not UTF-8 after percent-decoding")
}
