//! Gives the kernel back the pages of code that only start-up ran. Reading the configuration,
//! compiling the profiles and announcing Home Assistant discovery run once, but the pages of
//! their code and constants stay mapped for the life of the process, and the kernel maps the
//! neighbours of every page touched as well: on an edge box that is several MiB of a small
//! memory, held by code that never runs again. Once the gateway has settled, it asks the
//! kernel to reclaim the file-backed pages of its code and constants
//! (`madvise(MADV_PAGEOUT)`, Linux 5.4 and later); the pages the running loops use come back
//! on their next touch. The executable is written back to disk first: a page of a binary
//! installed just before the start may still be only in memory, and such a page cannot go.
//!
//! What comes back must be what the loops touch, not the code around it. A fault in a file
//! mapping reads ahead (`read_ahead_kb` of the disk: 128 KiB by default, 8 MiB on some hosts)
//! and maps the cached pages around the faulting one (64 KiB); both stay within the mapping.
//! Constants are advised `MADV_RANDOM` (no read-ahead). For code recent kernels read ahead
//! even then, so every other 16 KiB window of it (a page, where pages are larger) is advised
//! `MADV_RANDOM` as well: the kernel keeps such a window as a mapping of its own, and no fault
//! in the code brings back more than one window. On a host with an 8 MiB read-ahead that is
//! the difference between giving back a third of the code and giving back most of it.
//!
//! The write-back and the advice run on the blocking pool: neither may stall the lines.
//!
//! Safe by construction: the advice never changes memory contents. Clean file pages are
//! dropped and read again on use; the kernel leaves alone pages that other processes map (a
//! shared C library's); the private copies of relocated constants go to swap where there is
//! one and stay otherwise. On a kernel that does not know the advice nothing happens.

use std::ffi::c_void;
use std::os::fd::AsRawFd;
use std::time::Duration;

use tokio::sync::watch;

/// What one reclaim did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Reclaimed {
    /// Mappings paged out: the executable's and the libraries' segments on the first reclaim,
    /// and the windows the code was split into on later ones.
    pub mappings: usize,
    /// Ranges the kernel would not advise `MADV_RANDOM` (their pages went all the same).
    pub random_refused: usize,
    /// Bytes of address space advised.
    pub bytes: u64,
    /// VmRSS just before and just after, in KiB (0 where /proc could not be read).
    pub rss_before_kib: u64,
    pub rss_after_kib: u64,
}

/// One read-only, file-backed mapping of the process: code or constants.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Mapping {
    start: usize,
    len: usize,
    /// Code (`r-xp`) rather than constants.
    executable: bool,
}

/// The most a fault in the code may bring back once its pages are given back, where pages are
/// smaller. A quarter of the kernel's default fault-around (64 KiB): a touch brings back
/// little, and the code is kept as one mapping per 16 KiB (a few hundred for this
/// executable), not one per page.
const WINDOW: usize = 16 * 1024;

/// [`WINDOW`], or the page size where pages are larger (64 KiB on some ARM kernels): advice
/// is given in whole pages only.
fn code_window_len() -> usize {
    // SAFETY: sysconf takes no pointers.
    let page = unsafe { libc::sysconf(libc::_SC_PAGESIZE) };
    usize::try_from(page).map_or(WINDOW, |page| page.max(WINDOW))
}

impl Mapping {
    /// The ranges to advise `MADV_RANDOM`: all of a constants mapping; every other `window_len`
    /// bytes of a code mapping, counted from address 0 so that the same windows are chosen
    /// however the kernel has split the mapping since.
    fn random_access_ranges(self, window_len: usize) -> Vec<Mapping> {
        if !self.executable {
            return vec![self];
        }
        let end = self.start.saturating_add(self.len);
        let mut ranges = Vec::new();
        let mut window = self.start / window_len;
        while window.saturating_mul(window_len) < end {
            let window_start = window * window_len;
            if window % 2 == 0 {
                let start = window_start.max(self.start);
                let stop = window_start.saturating_add(window_len).min(end);
                ranges.push(Mapping {
                    start,
                    len: stop - start,
                    executable: true,
                });
            }
            window += 1;
        }
        ranges
    }
}

/// The process's file-backed code and constant mappings, from a `/proc/self/maps` text:
/// `r-xp` (code) and `r--p` (constants, the ELF headers) with an inode, so never the heap, a
/// stack, writable data or the kernel's vDSO.
fn code_and_constants(maps: &str) -> Vec<Mapping> {
    maps.lines()
        .filter_map(|line| {
            let mut fields = line.split_ascii_whitespace();
            let range = fields.next()?;
            let permissions = fields.next()?;
            let _offset = fields.next()?;
            let _device = fields.next()?;
            let inode = fields.next()?;
            if !matches!(permissions, "r-xp" | "r--p") || inode == "0" {
                return None;
            }
            let (start, end) = range.split_once('-')?;
            let start = usize::from_str_radix(start, 16).ok()?;
            let end = usize::from_str_radix(end, 16).ok()?;
            (end > start).then(|| Mapping {
                start,
                len: end - start,
                executable: permissions == "r-xp",
            })
        })
        .collect()
}

/// VmRSS of this process in KiB, 0 when it cannot be read.
fn rss_kib() -> u64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|status| {
            status
                .lines()
                .find(|line| line.starts_with("VmRSS:"))
                .and_then(|line| line.split_whitespace().nth(1))
                .and_then(|value| value.parse().ok())
        })
        .unwrap_or(0)
}

/// Asks the kernel to reclaim the pages of this process's code and constants now.
/// An error when `/proc/self/maps` cannot be read or the kernel refuses the advice (before
/// Linux 5.4: `EINVAL`).
pub fn reclaim() -> std::io::Result<Reclaimed> {
    let maps = std::fs::read_to_string("/proc/self/maps")?;
    let rss_before_kib = rss_kib();
    let mut reclaimed = Reclaimed {
        mappings: 0,
        random_refused: 0,
        bytes: 0,
        rss_before_kib,
        rss_after_kib: rss_before_kib,
    };
    let window_len = code_window_len();
    for mapping in code_and_constants(&maps) {
        // Random access first, so that what the loops fault back in comes without the
        // read-ahead around it; then the pages go, with the advice or without it.
        for range in mapping.random_access_ranges(window_len) {
            if advise(range, libc::MADV_RANDOM).is_err() {
                reclaimed.random_refused += 1;
            }
        }
        advise(mapping, libc::MADV_PAGEOUT)?;
        reclaimed.mappings += 1;
        reclaimed.bytes += mapping.len as u64;
    }
    reclaimed.rss_after_kib = rss_kib();
    Ok(reclaimed)
}

/// Gives `mapping` the advice `advice` (`MADV_RANDOM` or `MADV_PAGEOUT`).
fn advise(mapping: Mapping, advice: libc::c_int) -> std::io::Result<()> {
    // SAFETY: the range lies within one the kernel listed as mapped in this process a moment
    // ago; MADV_RANDOM only changes how much a fault reads ahead and MADV_PAGEOUT only where
    // the pages live, never what they contain (a later touch faults them back in unchanged),
    // so no reference into the range is affected. A range unmapped meanwhile makes the call
    // fail with ENOMEM, which is reported.
    let status = unsafe { libc::madvise(mapping.start as *mut c_void, mapping.len, advice) };
    if status == 0 {
        Ok(())
    } else {
        Err(std::io::Error::last_os_error())
    }
}

/// How long the kernel is given to write the executable back before its pages are released.
const WRITE_BACK_WAIT: Duration = Duration::from_secs(1);

/// Starts writing to disk whatever of the executable's file is still only in memory
/// (`sync_file_range`, which does not wait for the writes; it may wait for the disk's queue,
/// so it runs on the blocking pool). The kernel cannot give back a page that has not been
/// written yet, and a binary installed or upgraded just before the service (re)started is
/// written back only up to 30 s later (`vm.dirty_expire_centisecs`). Measured with the edge
/// build copied just before its start: one line kept 6.4 MiB without this, 2.4 MiB with it
/// (1.8 MiB for a binary written long before). `true` when the write-back was started
/// (nothing to write is done at once).
fn start_writing_back_executable() -> bool {
    let executable = match std::fs::File::open("/proc/self/exe") {
        Ok(executable) => executable,
        Err(error) => {
            tracing::debug!(%error, "the executable cannot be opened to write it back");
            return false;
        }
    };
    // SAFETY: the descriptor is open for the duration of the call; no memory is passed.
    let status =
        unsafe { libc::sync_file_range(executable.as_raw_fd(), 0, 0, libc::SYNC_FILE_RANGE_WRITE) };
    if status != 0 {
        let error = std::io::Error::last_os_error();
        tracing::debug!(%error, "the executable could not be written back before the release");
    }
    status == 0
}

/// Gives back the start-up code `settle` after start-up, and again that long after each
/// reload (a reload compiles profiles and validates the configuration again): each change of
/// `reloads` counts as one. Ends when `reloads` has no sender left.
pub async fn reclaim_after_settling<T>(settle: Duration, mut reloads: watch::Receiver<T>) {
    loop {
        tokio::time::sleep(settle).await;
        if let Ok(true) = tokio::task::spawn_blocking(start_writing_back_executable).await {
            tokio::time::sleep(WRITE_BACK_WAIT).await;
        }
        let released = tokio::task::spawn_blocking(reclaim)
            .await
            .unwrap_or_else(|error| Err(std::io::Error::other(error)));
        match released {
            Ok(done) => tracing::debug!(
                mappings = done.mappings,
                random_refused = done.random_refused,
                rss_before_kib = done.rss_before_kib,
                rss_after_kib = done.rss_after_kib,
                "start-up code pages given back to the kernel"
            ),
            Err(error) => {
                tracing::debug!(%error, "start-up code pages kept: the kernel refused the advice");
                return;
            }
        }
        if reloads.changed().await.is_err() {
            return;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MAPS: &str = "\
55d0c8a00000-55d0c8b00000 r--p 00000000 fe:01 1311 /usr/local/bin/rtu2mqtt
55d0c8b00000-55d0c9100000 r-xp 00100000 fe:01 1311 /usr/local/bin/rtu2mqtt
55d0c9100000-55d0c9140000 r--p 00700000 fe:01 1311 /usr/local/bin/rtu2mqtt
55d0c9140000-55d0c9142000 rw-p 00740000 fe:01 1311 /usr/local/bin/rtu2mqtt
55d0c9142000-55d0c9150000 rw-p 00000000 00:00 0
55d0ca000000-55d0ca100000 rw-p 00000000 00:00 0                          [heap]
7f1c2e000000-7f1c2e028000 r--p 00000000 fe:01 2002 /usr/lib/x86_64-linux-gnu/libc.so.6
7f1c2e028000-7f1c2e19d000 r-xp 00028000 fe:01 2002 /usr/lib/x86_64-linux-gnu/libc.so.6
7f1c2e19d000-7f1c2e1f5000 r--p 0019d000 fe:01 2002 /usr/lib/x86_64-linux-gnu/libc.so.6
7f1c2e1f5000-7f1c2e1f9000 rw-p 001f4000 fe:01 2002 /usr/lib/x86_64-linux-gnu/libc.so.6
7ffd1e2c1000-7ffd1e2e2000 rw-p 00000000 00:00 0                          [stack]
7ffd1e3e5000-7ffd1e3e9000 r--p 00000000 00:00 0                          [vvar]
7ffd1e3e9000-7ffd1e3eb000 r-xp 00000000 00:00 0                          [vdso]
";

    #[test]
    fn only_file_backed_code_and_constants_are_chosen() {
        let chosen = code_and_constants(MAPS);
        let starts: Vec<usize> = chosen.iter().map(|m| m.start).collect();
        assert_eq!(
            starts,
            vec![
                0x55d0c8a00000,
                0x55d0c8b00000,
                0x55d0c9100000,
                0x7f1c2e000000,
                0x7f1c2e028000,
                0x7f1c2e19d000
            ]
        );
        assert_eq!(chosen[1].len, 0x600000);
    }

    #[test]
    fn every_other_code_window_is_advised_random_and_all_constants() {
        let constants = Mapping {
            start: 0x10_0000,
            len: 0x1_0000,
            executable: false,
        };
        assert_eq!(constants.random_access_ranges(WINDOW), vec![constants]);
        // Code from 4 KiB into window 1 to 4 KiB into window 6 (of 16 KiB).
        let code = Mapping {
            start: WINDOW + 0x1000,
            len: 5 * WINDOW,
            executable: true,
        };
        let ranges: Vec<(usize, usize)> = code
            .random_access_ranges(WINDOW)
            .iter()
            .map(|range| (range.start / 0x1000, range.len / 0x1000))
            .collect();
        // Windows 2 and 4 whole, window 6 up to the end (4 KiB into it); window 0 is not in it.
        assert_eq!(ranges, vec![(8, 4), (16, 4), (24, 1)]);
        // A window already split off by an earlier reclaim is advised again, alone.
        let split = Mapping {
            start: 2 * WINDOW,
            len: WINDOW,
            executable: true,
        };
        assert_eq!(split.random_access_ranges(WINDOW), vec![split]);
        let odd = Mapping {
            start: 3 * WINDOW,
            len: WINDOW,
            executable: true,
        };
        assert!(odd.random_access_ranges(WINDOW).is_empty());
        // 64 KiB pages: whole pages, every other one.
        let big_pages = Mapping {
            start: 0x4_0000,
            len: 0x4_0000,
            executable: true,
        };
        let starts: Vec<usize> = big_pages
            .random_access_ranges(0x1_0000)
            .iter()
            .map(|range| range.start)
            .collect();
        assert_eq!(starts, vec![0x4_0000, 0x6_0000]);
        // A mapping at the top of the address space does not overflow.
        let top = Mapping {
            start: usize::MAX - 0x3fff - WINDOW,
            len: WINDOW,
            executable: true,
        };
        assert!(top.random_access_ranges(WINDOW).len() <= 2);
    }

    #[test]
    fn unreadable_lines_are_skipped() {
        let maps = "garbage\n1000-0800 r-xp 0 fe:01 7 /x\nzz-yy r-xp 0 fe:01 7 /x\n";
        assert!(code_and_constants(maps).is_empty());
    }

    #[test]
    fn this_kernel_takes_the_advice_for_every_mapping() {
        // The test's own process: its code runs on after the advice (it returns here).
        let done = reclaim().expect("MADV_PAGEOUT on this kernel");
        assert!(done.mappings >= 2 && done.bytes > 0, "{done:?}");
    }
}
