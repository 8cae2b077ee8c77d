//! A byte cursor shared by the readers: whitespace-separated text tokens with
//! line numbers, raw binary runs, and count capping so a header can never make
//! us allocate more than the file could hold.

use super::MeshError;
use std::path::Path;

/// How much of a bad token an error message quotes.
const QUOTE_MAX: usize = 40;

/// Quotes a token for an error message, shortened if long.
pub(crate) fn quote(t: &str) -> String {
    let mut s: String = t.chars().take(QUOTE_MAX).collect();
    if t.chars().count() > QUOTE_MAX {
        s.push('…');
    }
    s
}

pub(crate) struct Scan<'a> {
    path: &'a Path,
    data: &'a [u8],
    pos: usize,
    line: usize,
    comment: Option<u8>,
}

impl<'a> Scan<'a> {
    pub(crate) fn new(path: &'a Path, data: &'a [u8]) -> Self {
        Self::at_line(path, data, 1)
    }

    /// A cursor over a piece of a file that starts on line `line`.
    pub(crate) fn at_line(path: &'a Path, data: &'a [u8], line: usize) -> Self {
        Scan {
            path,
            data,
            pos: 0,
            line,
            comment: None,
        }
    }

    /// Treats `c` up to the end of the line as a comment (TetGen's `#`).
    pub(crate) fn with_comments(mut self, c: u8) -> Self {
        self.comment = Some(c);
        self
    }

    pub(crate) fn path(&self) -> &'a Path {
        self.path
    }
    pub(crate) fn line(&self) -> usize {
        self.line
    }
    pub(crate) fn pos(&self) -> usize {
        self.pos
    }
    pub(crate) fn remaining(&self) -> usize {
        self.data.len() - self.pos
    }

    /// A parse error at the current line.
    pub(crate) fn err(&self, msg: impl Into<String>) -> MeshError {
        self.err_at(self.line, msg)
    }

    /// A parse error at a given line.
    pub(crate) fn err_at(&self, line: usize, msg: impl Into<String>) -> MeshError {
        MeshError::Parse {
            path: self.path.to_path_buf(),
            line,
            msg: msg.into(),
        }
    }

    /// An error inside binary data, located by byte offset.
    pub(crate) fn bin_err(&self, msg: impl Into<String>) -> MeshError {
        MeshError::Binary {
            path: self.path.to_path_buf(),
            offset: self.pos,
            msg: msg.into(),
        }
    }

    /// At most `n`, and no more than the rest of the file could hold if each
    /// item took at least `min_bytes`: the capacity to reserve for `n` items a
    /// header declares.
    pub(crate) fn cap(&self, n: u64, min_bytes: usize) -> usize {
        let fit = self.remaining() / min_bytes.max(1);
        usize::try_from(n).unwrap_or(usize::MAX).min(fit)
    }

    pub(crate) fn skip_ws(&mut self) {
        while let Some(&b) = self.data.get(self.pos) {
            if b == b'\n' {
                self.line += 1;
                self.pos += 1;
            } else if b.is_ascii_whitespace() {
                self.pos += 1;
            } else if Some(b) == self.comment {
                while self.data.get(self.pos).is_some_and(|&c| c != b'\n') {
                    self.pos += 1;
                }
            } else {
                break;
            }
        }
    }

    /// Whether only whitespace (and comments) is left.
    pub(crate) fn at_eof(&mut self) -> bool {
        self.skip_ws();
        self.pos >= self.data.len()
    }

    /// The next whitespace-separated token; `what` names what was expected.
    pub(crate) fn token(&mut self, what: &str) -> Result<&'a str, MeshError> {
        self.skip_ws();
        if self.pos >= self.data.len() {
            return Err(self.err(format!("unexpected end of file: expected {what}")));
        }
        let start = self.pos;
        while let Some(&b) = self.data.get(self.pos) {
            if b.is_ascii_whitespace() || Some(b) == self.comment {
                break;
            }
            self.pos += 1;
        }
        std::str::from_utf8(&self.data[start..self.pos])
            .map_err(|_| self.err(format!("expected {what}, found bytes that are not text")))
    }

    /// The next token without consuming it (None at end of file or on non-text).
    pub(crate) fn peek(&mut self) -> Option<&'a str> {
        let (pos, line) = (self.pos, self.line);
        let t = self.token("").ok();
        self.pos = pos;
        self.line = line;
        t
    }

    /// Consumes the token `word` (case-sensitive) or fails naming it.
    pub(crate) fn expect(&mut self, word: &str) -> Result<(), MeshError> {
        let t = self.token(&format!("'{word}'"))?;
        if t == word {
            Ok(())
        } else {
            Err(self.err(format!("expected '{word}', found '{}'", quote(t))))
        }
    }

    pub(crate) fn f64(&mut self, what: &str) -> Result<f64, MeshError> {
        let t = self.token(what)?;
        t.parse::<f64>()
            .map_err(|_| self.err(format!("expected {what} (a number), found '{}'", quote(t))))
    }

    /// A number that must be finite (coordinates).
    pub(crate) fn finite(&mut self, what: &str) -> Result<f64, MeshError> {
        let v = self.f64(what)?;
        if v.is_finite() {
            Ok(v)
        } else {
            Err(self.err(format!("{what} is not finite ({v})")))
        }
    }

    pub(crate) fn u64(&mut self, what: &str) -> Result<u64, MeshError> {
        let t = self.token(what)?;
        t.parse::<u64>().map_err(|_| {
            self.err(format!(
                "expected {what} (a non-negative integer), found '{}'",
                quote(t)
            ))
        })
    }

    pub(crate) fn i64(&mut self, what: &str) -> Result<i64, MeshError> {
        let t = self.token(what)?;
        t.parse::<i64>()
            .map_err(|_| self.err(format!("expected {what} (an integer), found '{}'", quote(t))))
    }

    /// The rest of the current line (without its newline), consuming the newline.
    pub(crate) fn rest_of_line(&mut self) -> &'a [u8] {
        let start = self.pos;
        while self.data.get(self.pos).is_some_and(|&c| c != b'\n') {
            self.pos += 1;
        }
        let end = self.pos;
        if self.pos < self.data.len() {
            self.pos += 1;
            self.line += 1;
        }
        &self.data[start..end]
    }

    /// `n` raw bytes (binary data); newlines inside still advance the line count
    /// so later text errors point at the line an editor shows.
    pub(crate) fn bytes(&mut self, n: usize, what: &str) -> Result<&'a [u8], MeshError> {
        if self.remaining() < n {
            return Err(self.bin_err(format!(
                "file ends inside {what} ({n} bytes needed, {} left)",
                self.remaining()
            )));
        }
        let b = &self.data[self.pos..self.pos + n];
        self.line += b.iter().filter(|&&c| c == b'\n').count();
        self.pos += n;
        Ok(b)
    }

    /// Moves past the next occurrence of `needle`; false (at end) if none.
    pub(crate) fn skip_past(&mut self, needle: &[u8]) -> bool {
        let rest = &self.data[self.pos..];
        match rest.windows(needle.len()).position(|w| w == needle) {
            Some(i) => {
                let skipped = &rest[..i + needle.len()];
                self.line += skipped.iter().filter(|&&c| c == b'\n').count();
                self.pos += i + needle.len();
                true
            }
            None => {
                self.line += rest.iter().filter(|&&c| c == b'\n').count();
                self.pos = self.data.len();
                false
            }
        }
    }
}

/// Binary number decoding with a chosen byte order.
#[derive(Clone, Copy, Debug)]
pub(crate) enum Endian {
    Little,
    Big,
}

impl Endian {
    pub(crate) fn u64(self, b: &[u8]) -> u64 {
        let mut a = [0u8; 8];
        let n = b.len().min(8);
        match self {
            Endian::Little => {
                a[..n].copy_from_slice(&b[..n]);
                u64::from_le_bytes(a)
            }
            Endian::Big => {
                a[8 - n..].copy_from_slice(&b[..n]);
                u64::from_be_bytes(a)
            }
        }
    }
    /// A signed integer of 1, 2, 4 or 8 bytes.
    pub(crate) fn i64(self, b: &[u8]) -> i64 {
        let u = self.u64(b);
        let bits = 8 * b.len().clamp(1, 8) as u32;
        if bits == 64 {
            u as i64
        } else {
            // Sign-extend from `bits`.
            let shift = 64 - bits;
            ((u << shift) as i64) >> shift
        }
    }
    pub(crate) fn f64(self, b: &[u8]) -> f64 {
        f64::from_bits(self.u64(b))
    }
    pub(crate) fn f32(self, b: &[u8]) -> f64 {
        f64::from(f32::from_bits(self.u64(b) as u32))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tokens_lines_and_comments() {
        let p = Path::new("t");
        let mut s = Scan::new(p, b"a b # c d\n\n  e").with_comments(b'#');
        assert_eq!(s.token("x").unwrap(), "a");
        assert_eq!(s.token("x").unwrap(), "b");
        assert_eq!(s.token("x").unwrap(), "e");
        assert_eq!(s.line(), 3);
        assert!(s.at_eof());
        assert!(s.token("x").is_err());
    }

    #[test]
    fn cap_bounds_by_file_size() {
        let s = Scan::new(Path::new("t"), b"0123456789");
        assert_eq!(s.cap(u64::MAX, 2), 5);
        assert_eq!(s.cap(3, 2), 3);
    }

    #[test]
    fn endian_sign_extension() {
        assert_eq!(Endian::Big.i64(&[0xff, 0xff, 0xff, 0xfe]), -2);
        assert_eq!(Endian::Little.i64(&[1, 0, 0, 0]), 1);
        assert_eq!(Endian::Big.f64(&1.5f64.to_be_bytes()), 1.5);
    }
}
