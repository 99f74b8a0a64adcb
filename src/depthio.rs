//! Depth files into depth images (outside the core: this module touches files).
