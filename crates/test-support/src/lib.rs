//! Helpers shared by the workspace's tests; a dev-dependency of the crates that use them, never
//! a dependency of shipped code.

use std::collections::BTreeMap;
use std::path::Path;

/// Every file under `dir` (recursively), as (path relative to `dir`, bytes), sorted by path; a
/// folder that does not exist, or one that vanishes while read, contributes nothing.
pub fn files(dir: &Path) -> Vec<(String, Vec<u8>)> {
    file_map(dir).into_iter().collect()
}

/// [`files`] as a map from relative path to bytes.
pub fn file_map(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    let mut out = BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        let Ok(entries) = std::fs::read_dir(&d) else { continue };
        for e in entries.flatten() {
            let p = e.path();
            if p.is_dir() {
                stack.push(p);
            } else if let Ok(bytes) = std::fs::read(&p) {
                out.insert(p.strip_prefix(dir).unwrap_or(&p).display().to_string(), bytes);
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lists_nested_files_sorted_with_their_bytes() {
        let tmp = std::env::temp_dir().join(format!("test-support-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&tmp);
        std::fs::create_dir_all(tmp.join("b/c")).unwrap();
        std::fs::write(tmp.join("b/c/z.txt"), b"z").unwrap();
        std::fs::write(tmp.join("a.txt"), b"a").unwrap();
        let f = files(&tmp);
        let sep = std::path::MAIN_SEPARATOR;
        assert_eq!(f, vec![("a.txt".to_string(), b"a".to_vec()), (format!("b{sep}c{sep}z.txt"), b"z".to_vec())]);
        assert!(files(&tmp.join("missing")).is_empty());
        std::fs::remove_dir_all(&tmp).unwrap();
    }
}
