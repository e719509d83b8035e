//! The learner process's memory, for `/metrics`: what the kernel holds resident, and what the
//! program has allocated and not freed.
//!
//! The two answer different questions. Resident memory can step up and stay up without a
//! leak: glibc keeps freed memory for reuse (and `src/main.rs` raises its trim threshold so
//! candle's large temporaries are not returned and re-faulted every update), so a rare peak
//! of simultaneous allocations leaves a high-water mark. Bytes in use only grow with a leak.
//! The soak test (`scripts/soak.py`) samples both.
//!
//! [`release_free_memory`] hands what the allocator keeps back to the kernel; the learner does
//! it every [`RELEASE_EVERY`], so its resident memory follows what it uses instead of the
//! highest peak since start (which would look like a leak to whoever watches the process).
//! The first update after it faults its temporaries in again: a few milliseconds a minute.

/// How often the learner hands free memory back to the kernel.
pub const RELEASE_EVERY: std::time::Duration = std::time::Duration::from_secs(30);

/// Hands the allocator's free memory in every arena back to the kernel (glibc `malloc_trim`;
/// nothing elsewhere). Returns whether any was released.
pub fn release_free_memory() -> bool {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: malloc_trim takes the arena locks itself; it only releases free pages.
    unsafe {
        libc::malloc_trim(0) == 1
    }
    #[cfg(not(all(target_os = "linux", target_env = "gnu")))]
    false
}

/// One reading of the process's memory; `None` where it cannot be told.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ProcessMemory {
    /// Resident set size (`/proc/self/statm`), bytes.
    pub resident_bytes: Option<u64>,
    /// Bytes allocated and not freed ([`crate::alloc_count`]; `None` in a process that
    /// does not install its counting allocator, such as a test binary).
    pub heap_in_use_bytes: Option<u64>,
}

impl ProcessMemory {
    /// Reads it now.
    pub fn read() -> Self {
        Self { resident_bytes: resident(), heap_in_use_bytes: crate::alloc_count::in_use_bytes() }
    }
}

#[cfg(target_os = "linux")]
fn resident() -> Option<u64> {
    // statm: size resident shared text lib data dt, in pages.
    let statm = std::fs::read_to_string("/proc/self/statm").ok()?;
    let pages: u64 = statm.split_whitespace().nth(1)?.parse().ok()?;
    // SAFETY: sysconf only reads a system constant.
    let page = unsafe { libc::sysconf(libc::_SC_PAGESIZE) };
    u64::try_from(page).ok().map(|p| pages * p)
}

#[cfg(not(target_os = "linux"))]
fn resident() -> Option<u64> {
    None
}

#[cfg(all(test, target_os = "linux"))]
mod tests {
    use super::*;

    fn resident() -> i64 {
        ProcessMemory::read().resident_bytes.unwrap() as i64
    }

    /// One test, so the two steps do not run beside each other; the margins leave room for
    /// the other tests of this binary, which allocate and free beside it.
    #[test]
    fn resident_memory_follows_touched_pages_and_released_free_memory() {
        const MIB: i64 = 1 << 20;
        let before = resident();
        assert!(before > MIB, "{before}");
        // 256 MiB in 64 KiB blocks: below the mmap threshold, so they come from an arena and
        // stay there when freed; the last one stays allocated and pins the top of the heap.
        let mut blocks: Vec<Vec<u8>> = (0..4096).map(|_| vec![1u8; 64 << 10]).collect();
        std::hint::black_box(&blocks);
        let during = resident();
        assert!(during - before >= 192 * MIB, "{before} -> {during}");
        let pin = blocks.pop();
        drop(blocks);
        #[cfg(target_env = "gnu")]
        {
            let kept = resident();
            assert!(release_free_memory());
            let released = resident();
            assert!(kept - released >= 128 * MIB, "kept {kept} -> released {released}");
        }
        std::hint::black_box(pin);
    }
}
