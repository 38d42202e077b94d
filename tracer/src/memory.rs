//! Memory hints for the large arrays of scenes and trees.

/// Asks the kernel to back the whole 2 MiB pages inside `v`'s buffer with transparent
/// huge pages, now (Linux; elsewhere nothing). A large tree on 4 KiB pages costs a TLB
/// miss on nearly every node step near the root, and the system default here is
/// `madvise` (huge pages only where asked for). Contents and addresses are unchanged;
/// if the kernel declines, nothing changes. Used for the kd-tree's nodes and the scene's
/// triangle corners (`Geometry::permute_triangles`).
pub fn advise_huge_pages<T>(v: &[T]) {
    #[cfg(target_os = "linux")]
    {
        const HUGE: usize = 2 << 20;
        let start = v.as_ptr() as usize;
        let (lo, hi) = (start.next_multiple_of(HUGE), (start + size_of_val(v)) / HUGE * HUGE);
        if hi > lo {
            // SAFETY: [lo, hi) lies inside `v`'s allocation; both advices keep the memory's
            // contents and mapping (MADV_COLLAPSE copies populated pages into huge ones).
            unsafe {
                libc::madvise(lo as *mut libc::c_void, hi - lo, libc::MADV_HUGEPAGE);
                libc::madvise(lo as *mut libc::c_void, hi - lo, libc::MADV_COLLAPSE);
            }
        }
    }
    #[cfg(not(target_os = "linux"))]
    let _ = v;
}

/// Gives the C allocator's free memory back to the kernel (glibc's `malloc_trim`; on
/// other platforms nothing). A long-running process that frees large buffers — a farm
/// dropping a finished job's sums — otherwise keeps them in its resident size, spread
/// over the allocator's per-thread arenas.
pub fn return_free_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: malloc_trim has no preconditions: it only releases memory that is free.
    unsafe {
        libc::malloc_trim(0);
    }
}

/// Has the C allocator serve large buffers (128 KiB and up: images, unit results,
/// uploads) from their own mappings, returned to the kernel when freed (glibc's
/// `M_MMAP_THRESHOLD`; on other platforms nothing). By default glibc raises that
/// threshold each time such a buffer is freed, after which the same buffers come from
/// the heap and their freed space stays resident: a long-running farm grew by each job
/// it served. For servers; a render's own process does not need it.
pub fn return_large_buffers_when_freed() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only changes allocator tuning; any value is valid, and a fixed
    // threshold also turns off glibc's dynamic adjustment of it.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 128 * 1024);
    }
}
