//! Chunked encoding of fixed-size per-particle records.
//!
//! Writers fill a reusable buffer of [`CHUNK_RECORDS`] records and hand it to the sink in one
//! `write_all`, so encoding is a single pass with one allocation per file and bounded memory
//! (no per-value allocation, no whole-file buffer).
use std::io::{self, Write};

/// Records encoded per buffer fill.
pub(crate) const CHUNK_RECORDS: usize = 16 * 1024;

/// Encode `count` records of `stride` bytes: `fill(i, record)` writes record `i` into the
/// zero-initialised `record` slice (exactly `stride` bytes).
pub(crate) fn write_records<F>(
    w: &mut dyn Write,
    count: usize,
    stride: usize,
    mut fill: F,
) -> io::Result<()>
where
    F: FnMut(usize, &mut [u8]),
{
    if count == 0 || stride == 0 {
        return Ok(());
    }
    let mut buf = vec![0u8; CHUNK_RECORDS.min(count) * stride];
    let mut start = 0;
    while start < count {
        let end = (start + CHUNK_RECORDS).min(count);
        let bytes = &mut buf[..(end - start) * stride];
        for (i, record) in bytes.chunks_exact_mut(stride).enumerate() {
            fill(start + i, record);
        }
        w.write_all(bytes)?;
        start = end;
    }
    Ok(())
}

/// Store `v` little-endian at `record[at..at + 4]`.
#[inline(always)]
pub(crate) fn put_f32_le(record: &mut [u8], at: usize, v: f32) {
    record[at..at + 4].copy_from_slice(&v.to_le_bytes());
}

/// Store `v` big-endian at `record[at..at + 4]`.
#[inline(always)]
pub(crate) fn put_f32_be(record: &mut [u8], at: usize, v: f32) {
    record[at..at + 4].copy_from_slice(&v.to_be_bytes());
}
