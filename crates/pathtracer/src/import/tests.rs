//! Unit tests of the importer internals.
