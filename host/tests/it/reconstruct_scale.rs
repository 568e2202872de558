//! `reconstruct` streams and does not grow with the number of images: the same 10⁶ dots over
//! 20,000 images and over 2,000 give the same points with no allocation per dot (a row holds its
//! image's index, not a copy of its name; one record buffer is reused) and the same peak heap,
//! and 10⁶ dots need no more heap than 2·10⁵. Counted, not timed: the allocator of this test
//! binary counts what the threads of the test's own rayon pool allocate (the reconstruction runs
//! wholly on them). `deltaz bench-reconstruct` times it.

use deltaz_host::workflows::bench_reconstruct::ScalingInputs;
use deltaz_host::workflows::reconstruct::{reconstruct_stream, ReconstructArgs, StreamSummary};
use deltaz_shared::rig::Method;
use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::path::Path;
use std::sync::atomic::{AtomicIsize, AtomicUsize, Ordering};
use std::sync::Mutex;

thread_local! {
    /// Whether this thread's allocations are counted.
    static COUNTED: Cell<bool> = const { Cell::new(false) };
}

/// Allocations (and reallocations), live and peak bytes of the counted threads.
static ALLOCATIONS: AtomicUsize = AtomicUsize::new(0);
static LIVE: AtomicIsize = AtomicIsize::new(0);
static PEAK: AtomicIsize = AtomicIsize::new(0);

/// The system allocator, counting on the threads marked [`COUNTED`].
struct Counting;

fn counted() -> bool {
    COUNTED.try_with(Cell::get).unwrap_or(false)
}

fn note(bytes: isize, allocation: bool) {
    if allocation {
        ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
    }
    let live = LIVE.fetch_add(bytes, Ordering::Relaxed) + bytes;
    PEAK.fetch_max(live, Ordering::Relaxed);
}

// SAFETY: every call is forwarded unchanged to `System`, which upholds GlobalAlloc's contract;
// the counting touches only atomics and a const-initialised thread-local (no allocation).
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        // SAFETY: the caller's layout, as `GlobalAlloc::alloc` requires it.
        let p = unsafe { System.alloc(layout) };
        if !p.is_null() && counted() {
            note(layout.size() as isize, true);
        }
        p
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        if counted() {
            note(-(layout.size() as isize), false);
        }
        // SAFETY: `ptr` was allocated by `System` (through this allocator) with `layout`.
        unsafe { System.dealloc(ptr, layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        // SAFETY: as the caller guarantees for `GlobalAlloc::realloc`.
        let p = unsafe { System.realloc(ptr, layout, new_size) };
        if !p.is_null() && counted() {
            note(new_size as isize - layout.size() as isize, true);
        }
        p
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

/// What one reconstruction cost on the counted threads.
#[derive(Debug, Clone, Copy)]
struct Cost {
    allocations: usize,
    peak_bytes: isize,
}

/// `reconstruct` of `obs` (PLY and CSV) on a fresh two-thread pool whose threads are counted.
fn reconstruct_counted(system: &Path, obs: &Path, out: &Path) -> (StreamSummary, Cost) {
    // One measurement at a time: the counters are global.
    static ONE: Mutex<()> = Mutex::new(());
    let _one = ONE.lock().unwrap_or_else(|e| e.into_inner());
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(2)
        .start_handler(|_| COUNTED.with(|c| c.set(true)))
        .build()
        .unwrap();
    let args = ReconstructArgs {
        system: system.to_path_buf(),
        obs: obs.to_path_buf(),
        out: out.to_path_buf(),
        csv: Some(out.with_extension("csv")),
        ascii: false,
        sigma_px: None,
        method: Method::Paper,
        frame: None,
    };
    ALLOCATIONS.store(0, Ordering::Relaxed);
    LIVE.store(0, Ordering::Relaxed);
    PEAK.store(0, Ordering::Relaxed);
    let summary = pool.install(|| reconstruct_stream(&args)).unwrap();
    let cost = Cost {
        allocations: ALLOCATIONS.load(Ordering::Relaxed),
        peak_bytes: PEAK.load(Ordering::Relaxed),
    };
    (summary, cost)
}

/// The X, Y, Z (and miss) columns of a points CSV `image,point,X,Y,Z,miss`.
fn points(csv: &Path) -> Vec<String> {
    std::fs::read_to_string(csv)
        .unwrap()
        .lines()
        .skip(2)
        .map(|l| l.splitn(3, ',').nth(2).unwrap().to_owned())
        .collect()
}

#[test]
fn reconstruct_costs_the_same_over_2000_and_20000_images() {
    const DOTS: usize = 1_000_000;
    let dir = tempfile::tempdir().unwrap();
    let inputs = ScalingInputs::new(dir.path(), DOTS / 2_000).unwrap();
    let mut runs = Vec::new();
    for (dots, images) in [(DOTS, 2_000), (DOTS, 20_000), (DOTS / 5, 400)] {
        let obs = inputs.dots(dir.path(), dots, images).unwrap();
        let out = dir.path().join(format!("cloud_{images}.ply"));
        let (summary, cost) = reconstruct_counted(&inputs.system, &obs, &out);
        assert_eq!((summary.points, summary.images), (dots, images));
        // Exact dots: the rays meet (eqs 8-9 leave only the Y difference, rounding).
        assert!(summary.miss_rms < 1e-6, "{}", summary.miss_rms);
        std::fs::remove_file(obs).unwrap();
        eprintln!("{dots} dots over {images} images: {cost:?}");
        runs.push((images, cost, out.with_extension("csv")));
    }
    let [(_, few, few_csv), (_, many, many_csv), (_, fifth, _)] = &runs[..] else {
        unreachable!()
    };
    // The same points, whatever the number of images.
    assert!(points(few_csv) == points(many_csv));
    // Allocations: a few per image (its name, once) and per batch of 65,536 rows; none per dot.
    // A copy of the image name per dot, or a result vector per dot, is 10⁶ more.
    for (cost, images) in [(few, 2_000), (many, 20_000), (fifth, 400)] {
        assert!(
            cost.allocations < 4 * images + 20_000,
            "{} allocations over {images} images",
            cost.allocations
        );
    }
    // Peak heap: the batches in flight and their outputs (about 20 MB), not the dots (10⁶ rows of
    // 32 bytes and more); 18,000 more image names add about 2 MB; five times the dots add
    // nothing but rounding.
    let mb = |c: &Cost| c.peak_bytes as f64 / 1e6;
    assert!(mb(few) < 40.0 && mb(many) < 40.0, "{few:?} {many:?}");
    assert!((mb(many) - mb(few)).abs() < 4.0, "{few:?} {many:?}");
    assert!(
        (mb(few) - mb(fifth)).abs() < 0.1 * mb(fifth),
        "{few:?} {fifth:?}"
    );
}
