//! The baked-file reader on arbitrary bytes: what `bounce serve`, `relight`, `verify`, `inspect`
//! and the shard merge do with a file they are handed. Every reader of the format is run, and a
//! file that parses has its transport matrix decoded and applied once, as the CPU engine would:
//! the reader validates shapes and lengths so that the decoder can trust them, and this checks
//! that promise too, as the near-field correction does with its matrix. Any panic (including an arithmetic overflow: debug assertions are on) is a
//! bug; an error is the expected answer to a bad file.
#![no_main]

use bounce_core::codec;
use bounce_core::format::{Baked, FileSummary, ShardFile, ShardHeader};
use libfuzzer_sys::fuzz_target;

/// Larger matrices are decoded by the same code; a cap keeps each execution fast enough for
/// the fuzzer to explore (a 100 KiB input can name a matrix of millions of entries).
const MAX_DECODED_ENTRIES: usize = 1 << 20;

fuzz_target!(|data: &[u8]| {
    let _ = FileSummary::from_bytes(data);
    let _ = ShardHeader::from_bytes(data);
    let _ = ShardFile::from_bytes(data);
    let Ok(baked) = Baked::from_bytes(data) else {
        return;
    };
    let n = baked.transport.rows as usize;
    if n == 0 || n.saturating_mul(n) > MAX_DECODED_ENTRIES {
        return;
    }
    if let Ok(op) = codec::decode(&baked.transport) {
        let x = vec![[1.0f32; 3]; op.n()];
        let mut out = vec![[0.0f32; 3]; op.n()];
        let _ = op.matvec_batch(&x, &mut out);
    }
    // The near field's columns index every sample point and, through them, every row: the
    // reader's checks are what make the correction's indexing safe.
    if let (Some(near), Some(surface)) = (&baked.near_field, &baked.surface) {
        let rows = near.rows();
        let samples = rows * surface.per_patch as usize;
        if samples <= MAX_DECODED_ENTRIES {
            let _ = near.correction(
                &vec![[0.5f32; 3]; rows],
                &vec![[1.0f32; 3]; rows],
                &vec![[2.0f32; 3]; samples],
            );
        }
    }
    // A file that reads must write back: the writer trusts the values the reader accepted.
    let _ = baked.to_bytes();
});
