//! Transforms files from arbitrary bytes: parsed and checked as the dataset loader does before
//! it opens any frame file (intrinsics, every pose), through `dataset::check_transforms`. Any
//! error must be a value, never a panic, and an accepted file gives one camera per frame.
#![no_main]

use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|bytes: &[u8]| {
    if let Ok(cameras) = dataset::check_transforms(bytes, Path::new("fuzz.json"), (64, 48)) {
        let file = dataset::TransformsFile::from_slice(bytes, Path::new("fuzz.json")).expect("parsed once, parses again");
        assert_eq!(cameras.len(), file.frames.len());
    }
});
