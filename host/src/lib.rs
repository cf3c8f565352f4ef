//! Host side of the mirror mark test.
