//! Shared by the fuzz targets: an allocator that treats one allocation larger than
//! [`ALLOC_LIMIT`] as a crash. The inputs are at most a few tens of KiB, so an allocation that
//! size comes from a size field believed without a check against the bytes at hand (a decoder
//! bomb) and would abort the daemon on a flight computer. libFuzzer's own `-malloc_limit_mb`
//! needs a sanitizer's allocator hooks; the targets run without one for speed.

use std::alloc::{GlobalAlloc, Layout, System};
use std::io::Write;

/// The largest single allocation a target may make (256 MiB).
pub const ALLOC_LIMIT: usize = 256 << 20;

pub struct CappedAlloc;

impl CappedAlloc {
    #[cold]
    fn too_large(size: usize) -> ! {
        // Small allocations from here on pass through to `System` (re-entrancy is fine).
        let trace = std::backtrace::Backtrace::force_capture();
        let _ = writeln!(
            std::io::stderr(),
            "alfd-fuzz: allocation of {size} bytes (limit {ALLOC_LIMIT})\n{trace}"
        );
        // Unwinding out of an allocator is not allowed; libFuzzer reports the abort as a crash.
        std::process::abort()
    }
}

unsafe impl GlobalAlloc for CappedAlloc {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if layout.size() > ALLOC_LIMIT {
            Self::too_large(layout.size());
        }
        unsafe { System.alloc(layout) }
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        if layout.size() > ALLOC_LIMIT {
            Self::too_large(layout.size());
        }
        unsafe { System.alloc_zeroed(layout) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        if new_size > ALLOC_LIMIT {
            Self::too_large(new_size);
        }
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

/// Installs [`CappedAlloc`] in a fuzz target.
#[macro_export]
macro_rules! cap_allocations {
    () => {
        #[global_allocator]
        static ALLOC: $crate::CappedAlloc = $crate::CappedAlloc;
    };
}
