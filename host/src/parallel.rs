//! Independent work items spread over all cores, results in order (blobs of an image, dots of
//! a reconstruction batch).

/// `f(scratch, i)` for i in 0..count on all cores (threads take blocks of up to 16 as they
/// finish, smaller when there are few items so that every core gets some; each thread with its
/// own scratch), the results in the order of i.
pub fn parallel_map<S: Default, T: Send>(
    count: usize,
    f: impl Fn(&mut S, usize) -> T + Sync,
) -> Vec<T> {
    use std::sync::atomic::{AtomicUsize, Ordering};
    let next = AtomicUsize::new(0);
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
    // About four blocks per thread at least.
    let block = (count / (4 * threads)).clamp(1, 16);
    let work = || {
        let mut scratch = S::default();
        let mut done = Vec::new();
        loop {
            let start = next.fetch_add(block, Ordering::Relaxed);
            if start >= count {
                return done;
            }
            for i in start..(start + block).min(count) {
                done.push((i, f(&mut scratch, i)));
            }
        }
    };
    let mut all: Vec<(usize, T)> = std::thread::scope(|s| {
        let handles: Vec<_> = (1..threads.min(count.div_ceil(block)))
            .map(|_| s.spawn(work))
            .collect();
        let mut all = work();
        for h in handles {
            all.extend(h.join().expect("a worker thread panicked"));
        }
        all
    });
    all.sort_unstable_by_key(|(i, _)| *i);
    all.into_iter().map(|(_, t)| t).collect()
}
