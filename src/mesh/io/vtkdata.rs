//! Decoding of VTK XML binary data arrays: inline `format="binary"` (base64)
//! and `<AppendedData>` (raw or base64), uncompressed or zlib-compressed, with
//! UInt32 or UInt64 headers and either byte order — what ParaView and VTK
//! write by default.
//!
//! Layout (VTK file-format documentation): an uncompressed array is a header
//! holding its byte count, then the bytes. A compressed one has the header
//! `[nblocks, block size, last block size, compressed size × nblocks]`, then
//! the zlib blocks. In base64, VTK encodes the header and the data as two
//! separately padded runs (older writers encode them as one run; both are
//! read).

use super::scan::Endian;

/// How the arrays of a file are encoded (from `<VTKFile>`).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Encoding {
    pub(crate) endian: Endian,
    /// Bytes of a header integer (4 for UInt32, 8 for UInt64).
    pub(crate) header: usize,
    pub(crate) zlib: bool,
}

/// Where an array's bytes are.
pub(crate) enum Source<'a> {
    /// Base64 text (inline, or appended with `encoding="base64"`).
    Base64(&'a [u8]),
    /// Raw bytes (appended with `encoding="raw"`), from the array's offset on.
    Raw(&'a [u8]),
}

/// A cursor that reads runs of `n` bytes, each separately base64-encoded or raw.
struct Runs<'a> {
    src: &'a [u8],
    pos: usize,
    base64: bool,
}

impl Runs<'_> {
    /// Characters of base64 for `n` bytes.
    fn chars(n: usize) -> Option<usize> {
        n.checked_add(2).map(|m| m / 3).and_then(|g| g.checked_mul(4))
    }

    fn peek(&self, n: usize) -> Result<Vec<u8>, String> {
        let rest = &self.src[self.pos.min(self.src.len())..];
        if self.base64 {
            let c = Self::chars(n).ok_or("a run length overflows")?;
            let text = rest.get(..c).ok_or("base64 data ends early")?;
            let mut v = base64_decode(text)?;
            if v.len() < n {
                return Err("base64 data ends early".into());
            }
            v.truncate(n);
            Ok(v)
        } else {
            Ok(rest.get(..n).ok_or("raw data ends early")?.to_vec())
        }
    }

    fn take(&mut self, n: usize) -> Result<Vec<u8>, String> {
        let v = self.peek(n)?;
        self.pos += if self.base64 { Self::chars(n).unwrap_or(0) } else { n };
        Ok(v)
    }
}

/// Decodes standard base64, ignoring whitespace; `=` ends the data.
fn base64_decode(text: &[u8]) -> Result<Vec<u8>, String> {
    let mut out = Vec::with_capacity(text.len() / 4 * 3);
    let (mut acc, mut bits) = (0u32, 0u32);
    for &c in text {
        let v = match c {
            b'A'..=b'Z' => c - b'A',
            b'a'..=b'z' => c - b'a' + 26,
            b'0'..=b'9' => c - b'0' + 52,
            b'+' => 62,
            b'/' => 63,
            b'=' => break,
            c if c.is_ascii_whitespace() => continue,
            c => return Err(format!("byte 0x{c:02x} is not base64")),
        };
        acc = (acc << 6) | u32::from(v);
        bits += 6;
        if bits >= 8 {
            bits -= 8;
            out.push((acc >> bits) as u8);
            acc &= (1 << bits) - 1;
        }
    }
    Ok(out)
}

/// Removes whitespace (inline base64 may be wrapped over lines).
fn compact(text: &[u8]) -> Vec<u8> {
    text.iter().copied().filter(|c| !c.is_ascii_whitespace()).collect()
}

/// The decoded (and decompressed) bytes of one array, at most `max_bytes`
/// (what the declared counts need: a header cannot make us allocate more).
pub(crate) fn decode(src: Source, enc: Encoding, max_bytes: usize) -> Result<Vec<u8>, String> {
    let owned;
    let mut r = match src {
        Source::Base64(t) => {
            owned = compact(t);
            Runs {
                src: &owned,
                pos: 0,
                base64: true,
            }
        }
        Source::Raw(b) => Runs {
            src: b,
            pos: 0,
            base64: false,
        },
    };
    let h = enc.header;
    let int = |b: &[u8]| usize::try_from(enc.endian.u64(b)).map_err(|_| "a header value is too large".to_string());
    if !enc.zlib {
        let count = if r.base64 {
            // Header run separately padded, or one run with the data?
            let c = Runs::chars(h).unwrap_or(0);
            let separate = r.src.get(c.saturating_sub(1)) == Some(&b'=');
            if !separate {
                let head = r.peek(h)?;
                let count = int(&head)?;
                if count > max_bytes {
                    return Err(format!("declares {count} bytes, more than the {max_bytes} expected"));
                }
                let mut all = r.take(h + count)?;
                return Ok(all.split_off(h));
            }
            int(&r.take(h)?)?
        } else {
            int(&r.take(h)?)?
        };
        if count > max_bytes {
            return Err(format!("declares {count} bytes, more than the {max_bytes} expected"));
        }
        return r.take(count);
    }
    let first = r.peek(h)?;
    let nblocks = int(&first)?;
    // Every block needs at least a few bytes of input.
    if nblocks > r.src.len() {
        return Err(format!(
            "declares {nblocks} compressed blocks, more than the data could hold"
        ));
    }
    let head = r.take(h * (3 + nblocks))?;
    let field = |k: usize| int(&head[k * h..(k + 1) * h]);
    let block = field(1)?;
    let last = field(2)?;
    let mut out = Vec::new();
    let mut sizes = Vec::with_capacity(nblocks);
    for k in 0..nblocks {
        sizes.push(field(3 + k)?);
    }
    let total: usize = sizes
        .iter()
        .try_fold(0usize, |a, &s| a.checked_add(s))
        .ok_or("block sizes overflow")?;
    let data = r.take(total)?;
    let mut at = 0;
    for (k, &csize) in sizes.iter().enumerate() {
        let want = if k + 1 == nblocks && last != 0 { last } else { block };
        if out.len().saturating_add(want) > max_bytes {
            return Err(format!("decompresses to more than the {max_bytes} bytes expected"));
        }
        let mut dec = flate2::read::ZlibDecoder::new(&data[at..at + csize]);
        let mut buf = Vec::new();
        std::io::Read::read_to_end(&mut std::io::Read::take(&mut dec, want as u64), &mut buf)
            .map_err(|e| format!("compressed block {k}: {e}"))?;
        if buf.len() != want {
            return Err(format!("compressed block {k} holds {} bytes, not {want}", buf.len()));
        }
        out.extend_from_slice(&buf);
        at += csize;
    }
    Ok(out)
}

/// Bytes per value of a VTK XML type name, and whether it is a float.
pub(crate) fn type_size(ty: &str) -> Option<(usize, bool)> {
    Some(match ty {
        "Int8" | "UInt8" | "Char" => (1, false),
        "Int16" | "UInt16" => (2, false),
        "Int32" | "UInt32" => (4, false),
        "Int64" | "UInt64" => (8, false),
        "Float32" => (4, true),
        "Float64" => (8, true),
        _ => return None,
    })
}

/// Values of an array's decoded bytes, as f64 (exact for every integer an
/// index or a mask can hold).
pub(crate) fn to_f64(bytes: &[u8], ty: &str, endian: Endian) -> Option<Vec<f64>> {
    let (size, float) = type_size(ty)?;
    let unsigned = ty.starts_with('U');
    Some(
        bytes
            .chunks_exact(size)
            .map(|b| match (float, size) {
                (true, 4) => endian.f32(b),
                (true, _) => endian.f64(b),
                _ if unsigned => endian.u64(b) as f64,
                _ => endian.i64(b) as f64,
            })
            .collect(),
    )
}

/// Integer values of an array's decoded bytes (floats are refused).
pub(crate) fn to_i64(bytes: &[u8], ty: &str, endian: Endian) -> Option<Vec<i64>> {
    let (size, float) = type_size(ty)?;
    if float {
        return None;
    }
    let unsigned = ty.starts_with('U');
    Some(
        bytes
            .chunks_exact(size)
            .map(|b| {
                if unsigned {
                    i64::try_from(endian.u64(b)).unwrap_or(i64::MAX)
                } else {
                    endian.i64(b)
                }
            })
            .collect(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn base64_round() {
        assert_eq!(base64_decode(b"aGVsbG8=").unwrap(), b"hello");
        assert_eq!(base64_decode(b"aGVs\nbG8h").unwrap(), b"hello!");
        assert!(base64_decode(b"a*b").is_err());
    }

    #[test]
    fn uncompressed_separate_and_joint_base64() {
        let enc = Encoding {
            endian: Endian::Little,
            header: 4,
            zlib: false,
        };
        // header 4 bytes = [3,0,0,0] -> "AwAAAA==", data "abc" -> "YWJj"
        assert_eq!(decode(Source::Base64(b"AwAAAA==YWJj"), enc, 10).unwrap(), b"abc");
        // joint: [3,0,0,0,'a','b','c'] -> "AwAAAGFiYw=="
        assert_eq!(decode(Source::Base64(b"AwAAAGFiYw=="), enc, 10).unwrap(), b"abc");
        assert!(decode(Source::Base64(b"AwAAAA==YWJj"), enc, 2).is_err());
        assert_eq!(
            decode(Source::Raw(&[3, 0, 0, 0, 7, 8, 9, 1]), enc, 10).unwrap(),
            [7, 8, 9]
        );
    }
}
