//! A global allocator that counts the bytes in use, so a process can tell a leak (bytes in
//! use growing) from the allocator's high-water mark (resident memory that stays after a peak
//! because freed memory is kept for reuse). The `dvnav` binary installs it; the learner reports
//! the count in `/metrics` (`dvnav_heap_in_use_bytes`) and the soak test samples it.
//!
//! Cost: one relaxed atomic add per allocation and free, next to candle's megabyte buffers.

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicUsize, Ordering};

/// The system allocator, counting.
pub struct CountingAllocator;

static IN_USE: AtomicUsize = AtomicUsize::new(0);

// SAFETY: every call goes to `System` with the caller's arguments unchanged; the counter is
// only a side effect.
unsafe impl GlobalAlloc for CountingAllocator {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        // SAFETY: forwarded as is (the caller upholds `alloc`'s contract).
        let p = unsafe { System.alloc(layout) };
        if !p.is_null() {
            IN_USE.fetch_add(layout.size(), Ordering::Relaxed);
        }
        p
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        // SAFETY: forwarded as is.
        let p = unsafe { System.alloc_zeroed(layout) };
        if !p.is_null() {
            IN_USE.fetch_add(layout.size(), Ordering::Relaxed);
        }
        p
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: forwarded as is.
        unsafe { System.dealloc(ptr, layout) };
        IN_USE.fetch_sub(layout.size(), Ordering::Relaxed);
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        // SAFETY: forwarded as is.
        let p = unsafe { System.realloc(ptr, layout, new_size) };
        if !p.is_null() {
            // On failure the old block stays allocated and the count unchanged.
            IN_USE.fetch_add(new_size, Ordering::Relaxed);
            IN_USE.fetch_sub(layout.size(), Ordering::Relaxed);
        }
        p
    }
}

/// Bytes allocated and not freed, when this process counts them (the `dvnav` binary does;
/// test binaries do not).
pub fn in_use_bytes() -> Option<u64> {
    let n = IN_USE.load(Ordering::Relaxed);
    (n > 0).then_some(n as u64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_what_is_allocated_and_freed() {
        let a = CountingAllocator;
        let layout = Layout::from_size_align(1 << 20, 8).unwrap();
        let before = IN_USE.load(Ordering::Relaxed);
        // SAFETY: a non-zero layout; the block is freed with the same layout.
        unsafe {
            let p = a.alloc(layout);
            assert!(!p.is_null());
            assert_eq!(IN_USE.load(Ordering::Relaxed), before + (1 << 20));
            let p = a.realloc(p, layout, 3 << 20);
            assert!(!p.is_null());
            assert_eq!(IN_USE.load(Ordering::Relaxed), before + (3 << 20));
            a.dealloc(p, Layout::from_size_align(3 << 20, 8).unwrap());
        }
        assert_eq!(IN_USE.load(Ordering::Relaxed), before);
    }
}
