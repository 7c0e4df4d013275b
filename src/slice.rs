//! Sweep-plane slicer over a zmin-sorted triangle stream.
//!
//! PLACEHOLDER: being implemented (issue 3).
