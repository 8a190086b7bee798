//! The per-scan path allocates nothing after start-up: splitting a byte stream,
//! parsing replies, decoding 682-step MD scans and mapping their timestamps.
//! A counting global allocator proves it (this test binary only).

use smokenav_hokuyo_codec::{ClockSync, FrameSplitter, ReplyWriter, SyncConfig, parse_reply};
use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicU64, Ordering};

struct Counting;

static ALLOCATIONS: AtomicU64 = AtomicU64::new(0);

// SAFETY: forwards to the system allocator unchanged; only counts calls.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        // SAFETY: same contract as the caller's.
        unsafe { System.alloc(layout) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: `ptr` came from `System.alloc` with this layout.
        unsafe { System.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn decoding_a_stream_of_md_scans_allocates_nothing() {
    // Start-up: 100 scans of bytes, the splitter, the buffers.
    let mut stream = Vec::new();
    for k in 0..100u32 {
        let values = (0..682u32).map(|i| 20 + (i * 31 + k * 7) % 5000);
        let echo = format!("MD0044072501000;k{k}");
        ReplyWriter::new(&mut stream)
            .echo(echo.as_bytes())
            .status(*b"99")
            .time(k * 100)
            .data(3, values)
            .end();
    }
    let mut splitter = FrameSplitter::default();
    let mut ranges = [0u32; 1081];
    let mut sync = ClockSync::new(SyncConfig::default());
    let mut decoded = 0u32;
    let mut sum = 0u64;

    let before = ALLOCATIONS.load(Ordering::Relaxed);
    for (n, chunk) in stream.chunks(997).enumerate() {
        splitter.feed(chunk, |frame| {
            let reply = parse_reply(frame).expect("valid reply");
            let h = reply.decode_scan(&mut ranges, &mut []).expect("valid scan");
            sum += sync.on_scan(h.timestamp, 1_000_000_000 + n as u64 * 1_000_000);
            decoded += 1;
        });
    }
    let after = ALLOCATIONS.load(Ordering::Relaxed);
    assert_eq!(decoded, 100);
    assert!(sum > 0);
    assert_eq!(after - before, 0, "allocations while decoding 100 scans");
}
