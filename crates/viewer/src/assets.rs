//! The page's static files, embedded in the binary (no build step, no CDN): served by exact
//! path only, so no request can name anything else.

const INDEX: &str = include_str!("../assets/index.html");
const SCRIPT: &str = include_str!("../assets/viewer.js");
const STYLE: &str = include_str!("../assets/viewer.css");

/// The content type and bytes of the embedded file at request path `path`, if there is one.
pub fn asset(path: &str) -> Option<(&'static str, &'static [u8])> {
    match path {
        "/" | "/index.html" => Some(("text/html; charset=utf-8", INDEX.as_bytes())),
        "/viewer.js" => Some(("text/javascript; charset=utf-8", SCRIPT.as_bytes())),
        "/viewer.css" => Some(("text/css; charset=utf-8", STYLE.as_bytes())),
        _ => None,
    }
}
