//! The baked file format (in progress).
