//! glTF 2.0 import into the flat render scene (in progress).
