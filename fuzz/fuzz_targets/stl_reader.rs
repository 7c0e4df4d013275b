//! Fuzz target for `strata::stl::StlReader`.
//!
//! The first input byte picks a chunk size, the rest is the file. Checks: no panic; the chunked
//! parse equals the whole-buffer parse (facets bit for bit, summary or error); emitted facets
//! pass the reader's own checks; counts (facets, bad normals, trailing bytes) and offsets are
//! consistent; errors stick.
#![no_main]

use libfuzzer_sys::fuzz_target;
use strata::stl::{read_all, RawTriangle, StlErrorKind, StlReader, MAX_COORDINATE};

fn bits(t: &RawTriangle) -> [u32; 12] {
    let mut out = [0u32; 12];
    for (o, v) in out.iter_mut().zip(t.normal.iter().chain(t.vertices.iter().flatten())) {
        *o = v.to_bits();
    }
    out
}

fuzz_target!(|data: &[u8]| {
    let Some((&selector, file)) = data.split_first() else { return };
    // 1..=64 bytes for most selectors (token and record boundaries), a few larger sizes.
    let size = match selector {
        0..=191 => usize::from(selector % 64) + 1,
        192..=223 => 84,
        _ => 4096,
    };

    let mut whole = Vec::new();
    let whole_result = read_all(file, &mut |t| whole.push(bits(&t)));

    let mut reader = StlReader::new();
    let mut chunked = Vec::new();
    let mut chunked_result = None;
    for chunk in file.chunks(size) {
        if let Err(e) = reader.feed(chunk, &mut |t| chunked.push(t)) {
            // Errors stick.
            assert_eq!(reader.feed(b"x", &mut |_| panic!("facet after error")), Err(e));
            chunked_result = Some(Err(e));
            break;
        }
    }
    let chunked_result = chunked_result.unwrap_or_else(|| reader.finish());
    // A failed reader repeats its error; a finished one refuses more work.
    match (chunked_result, reader.finish()) {
        (Err(e), again) => assert_eq!(again, Err(e)),
        (Ok(_), again) => assert_eq!(again.map_err(|e| e.kind), Err(StlErrorKind::AfterFinish)),
    }

    assert_eq!(whole_result, chunked_result, "whole vs {size}-byte chunks");
    let chunked_bits: Vec<_> = chunked.iter().map(bits).collect();
    assert!(whole == chunked_bits, "facets differ in {size}-byte chunks");

    for t in &chunked {
        for v in t.vertices.iter().flatten() {
            assert!(v.is_finite() && v.abs() <= MAX_COORDINATE, "emitted coordinate {v}");
        }
        assert!(t.vertices[0] != t.vertices[1] || t.vertices[1] != t.vertices[2]);
    }
    match whole_result {
        Ok(s) => {
            assert_eq!(chunked.len() as u64, u64::from(s.triangles - s.degenerate));
            assert!(s.triangles > 0);
            // Every emitted facet with a NaN or infinite normal is counted as a bad normal.
            let bad = chunked.iter().filter(|t| t.normal.iter().any(|v| !v.is_finite())).count();
            assert!(bad as u64 <= u64::from(s.bad_normals) && s.bad_normals <= s.triangles);
            assert!(u64::from(s.trailing_bytes) <= file.len() as u64);
        }
        Err(e) => assert!(e.offset <= file.len() as u64, "offset {} past the end", e.offset),
    }
});
