//! URI handling for glTF buffers and images: `data:` URIs (base64), percent-decoded relative
//! paths. Written here rather than taken from a crate so every failure is a typed message.

use std::path::{Path, PathBuf};

/// Where a glTF `uri` points.
#[derive(Debug, PartialEq, Eq)]
pub(crate) enum UriTarget {
    /// Inline bytes of a `data:` URI, with its MIME type (may be empty).
    Data {
        /// MIME type from the URI (`application/octet-stream`, `image/png`, ...).
        mime: String,
        /// Decoded payload.
        bytes: Vec<u8>,
    },
    /// A file relative to the glTF file's folder (already percent-decoded).
    File(PathBuf),
}

/// Resolves a glTF `uri` against `base_dir`. Errors are plain messages; the caller adds the
/// scene file and the referencing object.
pub(crate) fn resolve(uri: &str, base_dir: Option<&Path>) -> Result<UriTarget, String> {
    if let Some(rest) = uri.strip_prefix("data:") {
        let (header, payload) = rest
            .split_once(',')
            .ok_or_else(|| "malformed data: URI (no ',' before the payload)".to_string())?;
        let (mime, is_base64) = match header.strip_suffix(";base64") {
            Some(mime) => (mime, true),
            None => (header, false),
        };
        let bytes = if is_base64 {
            decode_base64(payload)?
        } else {
            percent_decode(payload)?
        };
        return Ok(UriTarget::Data { mime: mime.to_string(), bytes });
    }
    if let Some((scheme, _)) = uri.split_once(':') {
        // A URI scheme is letters, digits, '+', '-', '.', starting with a letter; one letter
        // is a Windows drive, which we treat as a path.
        let is_scheme = scheme.len() > 1
            && scheme.chars().next().is_some_and(|c| c.is_ascii_alphabetic())
            && scheme.chars().all(|c| c.is_ascii_alphanumeric() || "+-.".contains(c));
        if is_scheme {
            return Err(format!("unsupported URI scheme '{scheme}:' in '{uri}' (only relative paths and data: URIs)"));
        }
    }
    let decoded = percent_decode(uri)?;
    let decoded = String::from_utf8(decoded).map_err(|_| format!("URI '{uri}' is not UTF-8 after percent-decoding"))?;
    let relative = Path::new(&decoded);
    let base = base_dir.ok_or_else(|| {
        format!("external file '{decoded}' cannot be resolved: no base directory (scene loaded from memory)")
    })?;
    Ok(UriTarget::File(base.join(relative)))
}

/// Decodes `%XX` escapes (RFC 3986).
pub(crate) fn percent_decode(s: &str) -> Result<Vec<u8>, String> {
    let bytes = s.as_bytes();
    let mut out = Vec::with_capacity(bytes.len());
    let mut i = 0;
    while let Some(&b) = bytes.get(i) {
        if b == b'%' {
            let hi = bytes.get(i + 1).and_then(|c| hex_value(*c));
            let lo = bytes.get(i + 2).and_then(|c| hex_value(*c));
            match (hi, lo) {
                (Some(hi), Some(lo)) => out.push(hi << 4 | lo),
                _ => return Err(format!("invalid percent escape in '{s}'")),
            }
            i += 3;
        } else {
            out.push(b);
            i += 1;
        }
    }
    Ok(out)
}

fn hex_value(c: u8) -> Option<u8> {
    match c {
        b'0'..=b'9' => Some(c - b'0'),
        b'a'..=b'f' => Some(c - b'a' + 10),
        b'A'..=b'F' => Some(c - b'A' + 10),
        _ => None,
    }
}

/// Decodes standard base64 (RFC 4648, `+/`, optional `=` padding; ASCII whitespace ignored;
/// the URL-safe alphabet `-_` is accepted too).
pub(crate) fn decode_base64(s: &str) -> Result<Vec<u8>, String> {
    let mut out = Vec::with_capacity(s.len() / 4 * 3 + 3);
    let mut acc: u32 = 0;
    let mut bits = 0u32;
    let mut padding = 0usize;
    for (pos, c) in s.bytes().enumerate() {
        let v = match c {
            b'A'..=b'Z' => c - b'A',
            b'a'..=b'z' => c - b'a' + 26,
            b'0'..=b'9' => c - b'0' + 52,
            b'+' | b'-' => 62,
            b'/' | b'_' => 63,
            b'=' => {
                padding += 1;
                continue;
            }
            b' ' | b'\n' | b'\r' | b'\t' => continue,
            _ => return Err(format!("invalid base64 character {:?} at offset {pos}", c as char)),
        };
        if padding > 0 {
            return Err(format!("base64 data continues after '=' padding at offset {pos}"));
        }
        acc = (acc << 6) | u32::from(v);
        bits += 6;
        if bits >= 8 {
            bits -= 8;
            out.push((acc >> bits) as u8);
            acc &= (1 << bits) - 1;
        }
    }
    if bits >= 6 {
        return Err("truncated base64 data".to_string());
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn base64_known_vectors() {
        // RFC 4648 section 10 test vectors.
        for (plain, enc) in [
            ("", ""),
            ("f", "Zg=="),
            ("fo", "Zm8="),
            ("foo", "Zm9v"),
            ("foob", "Zm9vYg=="),
            ("fooba", "Zm9vYmE="),
            ("foobar", "Zm9vYmFy"),
        ] {
            assert_eq!(decode_base64(enc).unwrap(), plain.as_bytes(), "{enc}");
        }
        assert_eq!(decode_base64("Zm9v\nYmFy").unwrap(), b"foobar");
        assert!(decode_base64("Zm9v!").is_err());
        assert!(decode_base64("Z").is_err());
        assert!(decode_base64("Zg==Zg").is_err());
    }

    #[test]
    fn percent_decoding_and_resolution() {
        assert_eq!(percent_decode("a%20b%2Fc").unwrap(), b"a b/c");
        assert!(percent_decode("a%2").is_err());
        assert!(percent_decode("a%zz").is_err());
        let base = Path::new("/scenes");
        assert_eq!(resolve("my%20file.bin", Some(base)).unwrap(), UriTarget::File(PathBuf::from("/scenes/my file.bin")));
        assert_eq!(
            resolve("data:application/octet-stream;base64,AAEC", None).unwrap(),
            UriTarget::Data { mime: "application/octet-stream".into(), bytes: vec![0, 1, 2] }
        );
        assert!(resolve("https://example.com/a.bin", Some(base)).unwrap_err().contains("https"));
        assert!(resolve("a.bin", None).unwrap_err().contains("a.bin"));
        assert!(resolve("data:nocomma", None).is_err());
    }
}
