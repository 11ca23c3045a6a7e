//! The process's memory: the allocator the `psao` binary runs on, handing
//! freed setup scratch back to the system, and the resident size.
//!
//! Setup builds large scratch (spawned points, neighbour lists, per-thread
//! chunks) and frees it. glibc's allocator keeps much of that in its arenas
//! (its mmap threshold grows with every large block freed), so a server of
//! 5 million points held about 130 bytes per point where its data needs
//! under 100. jemalloc (the default feature `jemalloc`; not on MSVC)
//! returns freed pages on a decay clock, and [`release_freed`] makes it
//! return them at once when setup ends.

#[cfg(all(feature = "jemalloc", not(target_env = "msvc")))]
#[global_allocator]
static ALLOCATOR: tikv_jemallocator::Jemalloc = tikv_jemallocator::Jemalloc;

/// Hands the pages of freed memory back to the system now, instead of
/// after the allocator's decay time (10 s by default, and only while the
/// process allocates). Returns whether the allocator did so; `false` where
/// the binary runs on the system allocator.
pub fn release_freed() -> bool {
    #[cfg(all(feature = "jemalloc", not(target_env = "msvc")))]
    {
        use tikv_jemalloc_ctl::{Access as _, AsName as _};
        let Ok(arenas) = tikv_jemalloc_ctl::arenas::narenas::read() else {
            return false;
        };
        let mut released = false;
        for arena in 0..arenas {
            for kind in ["dirty", "muzzy"] {
                // Setting an arena's decay time to 0 purges its unused pages
                // of that kind at once (jemalloc's `arena.<i>.*_decay_ms`);
                // the old time is then restored. An arena that was never
                // created answers an error and is skipped.
                let key = format!("arena.{arena}.{kind}_decay_ms\0");
                let name = key.as_bytes().name();
                let ms: isize = match name.read() {
                    Ok(ms) => ms,
                    Err(_) => continue,
                };
                released |= name.write(0isize).is_ok();
                let _ = name.write(ms);
            }
        }
        released
    }
    #[cfg(not(all(feature = "jemalloc", not(target_env = "msvc"))))]
    false
}

/// Resident and peak resident bytes of this process (`VmRSS` and `VmHWM`
/// of `/proc/self/status`); `None` off Linux or if it cannot be read.
pub fn resident() -> Option<(u64, u64)> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let field = |name: &str| -> Option<u64> {
        let line = status.lines().find(|l| l.starts_with(name))?;
        let kib: u64 = line[name.len()..]
            .trim()
            .strip_suffix("kB")?
            .trim()
            .parse()
            .ok()?;
        Some(kib * 1024)
    };
    Some((field("VmRSS:")?, field("VmHWM:")?))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Setup-like scratch (many 64 KiB blocks, written, then freed) stays
    /// resident until [`release_freed`] hands it back.
    #[test]
    fn freed_scratch_is_handed_back_on_release() {
        let Some((before, _)) = resident() else {
            return; // not Linux: nothing to read
        };
        // 512 MiB, so that what other tests of this process allocate or
        // free meanwhile (tens of MB) cannot decide the outcome.
        const MB: u64 = 1 << 20;
        let blocks: Vec<Vec<u8>> = (0..8192).map(|k| vec![k as u8 | 1; 64 << 10]).collect();
        let (held, _) = resident().unwrap();
        assert!(held >= before + 400 * MB, "{before} -> {held}");
        drop(std::hint::black_box(blocks));
        let jemalloc = cfg!(all(feature = "jemalloc", not(target_env = "msvc")));
        if jemalloc {
            // Negative control: freed, but kept by the allocator.
            let (kept, _) = resident().unwrap();
            assert!(kept + 200 * MB > held, "{held} -> {kept}");
        }
        assert_eq!(release_freed(), jemalloc);
        if jemalloc {
            let (after, _) = resident().unwrap();
            assert!(after + 400 * MB <= held, "{held} -> {after}");
        }
    }
}
