//! A request target split into its path (kept as sent, never decoded, so that it is matched
//! exactly against the known routes) and its query parameters (percent-decoded, `+` as space).

use crate::error::{ViewerError, bad};

/// A parsed request target.
#[derive(Clone, Debug, PartialEq)]
pub struct Target {
    /// The path as sent (`/api/render`).
    pub path: String,
    /// The query's `name=value` pairs, decoded, in order.
    pub params: Vec<(String, String)>,
}

impl Target {
    /// Splits `url` (`/path?a=1&b=2`) into path and decoded parameters; a parameter that is not
    /// valid percent-encoded UTF-8 is a 400 naming it.
    pub fn parse(url: &str) -> Result<Self, ViewerError> {
        let (path, query) = url.split_once('?').unwrap_or((url, ""));
        let mut params = Vec::new();
        for pair in query.split('&').filter(|p| !p.is_empty()) {
            let (k, v) = pair.split_once('=').unwrap_or((pair, ""));
            let k = decode(k).ok_or_else(|| bad(format!("query parameter '{k}' is not valid percent-encoded UTF-8")))?;
            let v = decode(v).ok_or_else(|| bad(format!("query parameter '{k}': its value is not valid percent-encoded UTF-8")))?;
            params.push((k, v));
        }
        Ok(Self { path: path.to_string(), params })
    }

    /// The first value of parameter `name`.
    pub fn get(&self, name: &str) -> Option<&str> {
        self.params.iter().find(|(k, _)| k == name).map(|(_, v)| v.as_str())
    }

    /// Parameter `name`, required.
    pub fn required(&self, name: &str) -> Result<&str, ViewerError> {
        self.get(name).ok_or_else(|| bad(format!("missing query parameter '{name}'")))
    }

    /// Parameter `name` as a number of type `T`, `default` when absent.
    pub fn number<T: std::str::FromStr>(&self, name: &str, default: Option<T>) -> Result<T, ViewerError> {
        match (self.get(name), default) {
            (Some(v), _) => v.trim().parse().map_err(|_| bad(format!("parameter '{name}' = '{v}' is not a number of the expected kind"))),
            (None, Some(d)) => Ok(d),
            (None, None) => Err(bad(format!("missing query parameter '{name}'"))),
        }
    }
}

/// Percent-decoding with `+` as a space; `None` for a bad escape or bytes that are not UTF-8.
fn decode(s: &str) -> Option<String> {
    let b = s.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        match b[i] {
            b'%' => {
                let hex = std::str::from_utf8(b.get(i + 1..i + 3)?).ok()?;
                out.push(u8::from_str_radix(hex, 16).ok()?);
                i += 3;
            }
            b'+' => {
                out.push(b' ');
                i += 1;
            }
            c => {
                out.push(c);
                i += 1;
            }
        }
    }
    String::from_utf8(out).ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn path_is_kept_and_parameters_decoded() {
        let t = Target::parse("/api/gt?view=3&kind=rgb&c2w=1%2C0%2C0+&x").unwrap();
        assert_eq!(t.path, "/api/gt");
        assert_eq!(t.get("view"), Some("3"));
        assert_eq!(t.get("c2w"), Some("1,0,0 "));
        assert_eq!(t.get("x"), Some(""));
        assert_eq!(t.number::<u32>("view", None).unwrap(), 3);
        assert!(t.number::<u32>("kind", None).is_err());
        assert_eq!(Target::parse("/%2e%2e/etc").unwrap().path, "/%2e%2e/etc");
        assert!(Target::parse("/a?v=%zz").is_err());
        assert!(Target::parse("/a?v=%ff").is_err());
    }
}
