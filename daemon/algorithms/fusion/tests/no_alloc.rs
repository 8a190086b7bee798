//! The hot path allocates nothing: after the first cycles, a fusion cycle
//! through the synchroniser and the v1/v2 engine makes no heap allocation.

use smokenav_algorithms_fusion::pipeline::FusionPipeline;
use smokenav_algorithms_fusion::testkit::{Room, smoke_reading, smoky_scan};
use smokenav_platform_config::RobotConfig;
use smokenav_shared_types::{FusedScan, FusionMethod, SmokeTrend};
use std::alloc::{GlobalAlloc, Layout, System};
use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, Ordering};

struct Counting;

static ALLOCS: AtomicU64 = AtomicU64::new(0);

// SAFETY: forwards to the system allocator unchanged; only counts calls.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        ALLOCS.fetch_add(1, Ordering::Relaxed);
        // SAFETY: same contract as the caller's.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: same contract as the caller's.
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        ALLOCS.fetch_add(1, Ordering::Relaxed);
        // SAFETY: same contract as the caller's.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn steady_state_cycles_do_not_allocate() {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../config/nomad-scout.toml");
    let cfg = RobotConfig::load(&p).unwrap();
    for method in [FusionMethod::V1, FusionMethod::V2] {
        let mut pipeline = FusionPipeline::from_config(&cfg, Some(method)).unwrap();
        let room = Room::default();
        let geometry = pipeline.engine().geometry().clone();
        // Inputs built up front: building them is not the hot path.
        let inputs: Vec<_> = (0..40u64)
            .map(|k| {
                let t = 1_000_000_000 + k * 100_000_000;
                let dense = k % 2 == 0;
                let scan = if dense {
                    smoky_scan(t, k)
                } else {
                    room.scan(t, k)
                };
                let ring = room.ring(&geometry, 10.0, t + 1_000_000, k);
                let smoke = smoke_reading(
                    t + 2_000_000,
                    k,
                    if dense { 250.0 } else { 0.0 },
                    SmokeTrend::Rising,
                );
                (t, Box::new(scan), ring, smoke)
            })
            .collect();
        let mut outputs = 0u64;
        let mut emit = |_: &FusedScan, _: &_| outputs += 1;
        let mut run = |range: std::ops::Range<usize>, emit: &mut dyn FnMut(&FusedScan, &_)| {
            for (t, scan, ring, smoke) in &inputs[range] {
                pipeline.push_laser(scan, *t, &mut |f: &FusedScan, r: &_| emit(f, r));
                pipeline.push_sonar(ring, t + 1_000_000, &mut |f: &FusedScan, r: &_| emit(f, r));
                pipeline.push_smoke(smoke, t + 2_000_000, &mut |f: &FusedScan, r: &_| emit(f, r));
            }
        };
        run(0..4, &mut emit);
        let before = ALLOCS.load(Ordering::Relaxed);
        run(4..40, &mut emit);
        let after = ALLOCS.load(Ordering::Relaxed);
        assert_eq!(after - before, 0, "{method:?}: allocations in 36 cycles");
        assert_eq!(outputs, 40, "{method:?}");
    }
}
