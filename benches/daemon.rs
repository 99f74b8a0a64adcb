//! The daemon load benchmark: being written.
fn main() {}
