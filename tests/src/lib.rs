//! End-to-end tests across crates (render → train → eval) live in `tests/tests/`; the set-up
//! they share (scene paths, small renders, training builders) is in `crates/test-support`.
