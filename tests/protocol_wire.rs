//! Wire formats: golden bytes (frames, messages, triangles), round trips of every message,
//! the decoder's resynchronisation and its refusal of every corrupted frame.

use proptest::prelude::*;
use strata::geom::{Point3, Triangle};
use strata::machine::PrintSettings;
use strata::protocol::frame::{self, FrameType, MAX_WIRE};
use strata::protocol::msg::{decode_triangle, encode_triangle};
use strata::protocol::{
    job_fingerprint, BatchBuilder, Capacities, Decoder, DeviceState, ErrorCode, FrameError,
    GcodeSpec, JobOptions, JobSpec, Message, ParkedJob, Status, MAX_PAYLOAD, VERSION,
};

fn wire(kind: FrameType, seq: u8, ack: u8, credits: u8, payload: &[u8]) -> Vec<u8> {
    let mut out = [0u8; MAX_WIRE];
    let n = frame::encode(kind, seq, ack, credits, payload, &mut out).unwrap();
    out[..n].to_vec()
}

/// A decoded frame: type, seq, ack, credits, payload.
type Owned = (FrameType, u8, u8, u8, Vec<u8>);

fn decode_all(bytes: &[u8]) -> Vec<Result<Owned, FrameError>> {
    let mut d = Decoder::new();
    let mut out = Vec::new();
    for &b in bytes {
        if let Some(r) = d.push(b) {
            out.push(r.map(|f| (f.kind, f.seq, f.ack, f.credits, f.payload.to_vec())));
        }
    }
    out
}

#[test]
fn golden_ack_frame() {
    // [0x81 (v8, ack), seq 0, ack 3, credits 4] + CRC-32/ISO-HDLC LE, COBS, 0x00.
    assert_eq!(VERSION, 8);
    let w = wire(FrameType::Ack, 0, 3, 4, &[]);
    let crc = crc32(&[0x81, 0x00, 0x03, 0x04]);
    let mut raw = vec![0x81, 0x00, 0x03, 0x04];
    raw.extend_from_slice(&crc.to_le_bytes());
    assert_eq!(w, cobs(&raw));
    assert_eq!(w, GOLDEN_ACK.to_vec());
}

// Derived with Python's zlib.crc32 (CRC-32/ISO-HDLC) and a hand COBS.
// CRC 0x58e19998; COBS: [0x81] then the six non-zero bytes after the zero seq byte.
const GOLDEN_ACK: [u8; 10] = [2, 129, 7, 3, 4, 152, 153, 225, 88, 0];

#[test]
fn golden_open_frame() {
    let w = wire(FrameType::Open, 0xa5, 0, 4, &[]);
    assert_eq!(w, GOLDEN_OPEN.to_vec());
    let r = decode_all(&w);
    assert_eq!(r, vec![Ok((FrameType::Open, 0xa5, 0, 4, vec![]))]);
}

// [0x82 (v8, open), nonce 0xa5, ack 0, credits 4, CRC 0xbecafa3e]: the zero ack byte ends
// the first COBS run.
const GOLDEN_OPEN: [u8; 10] = [3, 130, 165, 6, 4, 62, 250, 202, 190, 0];

#[test]
fn golden_hello_frame() {
    let mut buf = [0u8; 8];
    let n = Message::Hello { version: VERSION }.encode(&mut buf).unwrap();
    assert_eq!(&buf[..n], &[0x01, 0x08]);
    let w = wire(FrameType::Data, 7, 0, 8, &buf[..n]);
    assert_eq!(w, GOLDEN_HELLO.to_vec());
}

// [0x80 (v8, data), seq 7, ack 0, credits 8, 0x01 Hello, version 8, CRC 0x048181a0] COBS: the
// zero ack byte becomes a code byte.
const GOLDEN_HELLO: [u8; 12] = [3, 128, 7, 8, 8, 1, 8, 160, 129, 129, 4, 0];

/// Capacities used by the golden and round-trip tests.
const SAMPLE_CAPS: Capacities = Capacities {
    active_triangles: 1024,
    contour_points: 768,
    contour_loops: 48,
    move_buffer_bytes: 4096,
    layer_window: 4,
    ram_bytes: 65536,
    toolpath_points: 80,
    toolpath_loops: 4,
    scan_crossings: 128,
    path_points: 320,
    window_ring_words: 192,
    window_spans: 64,
};

#[test]
fn golden_capabilities() {
    let caps = SAMPLE_CAPS;
    let mut buf = [0u8; MAX_PAYLOAD];
    let n = Message::Capabilities { version: VERSION, capacities: caps }.encode(&mut buf).unwrap();
    assert_eq!(&buf[..n], &GOLDEN_CAPABILITIES);
    let back = Message::decode(&GOLDEN_CAPABILITIES).unwrap();
    assert_eq!(back, Message::Capabilities { version: 8, capacities: caps });
}

// Type 0x02, version 8, then little-endian: active triangles 1024, contour points 768, loops 48,
// move buffer bytes 4096 (u32 each), layer window 4 (u16), RAM 65536 (u32), then the toolpath's
// PTS 80, LOOPS 4, CROSS 128, PATH 320, RING 192, SPANS 64 (u32 each): 48 bytes.
#[rustfmt::skip]
const GOLDEN_CAPABILITIES: [u8; 48] = [
    0x02, 8,
    0x00, 0x04, 0, 0,  0x00, 0x03, 0, 0,  48, 0, 0, 0,  0x00, 0x10, 0, 0,
    4, 0,
    0x00, 0x00, 0x01, 0,
    80, 0, 0, 0,  4, 0, 0, 0,  128, 0, 0, 0,  0x40, 0x01, 0, 0,  192, 0, 0, 0,  64, 0, 0, 0,
];

/// Bitwise CRC-32/ISO-HDLC, independent of the `crc` crate.
fn crc32(data: &[u8]) -> u32 {
    let mut c = !0u32;
    for &b in data {
        c ^= b as u32;
        for _ in 0..8 {
            c = if c & 1 != 0 { c >> 1 ^ 0xEDB8_8320 } else { c >> 1 };
        }
    }
    !c
}

/// Reference COBS with the delimiter.
fn cobs(raw: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    for chunk in raw.split(|&b| b == 0) {
        let mut rest = chunk;
        loop {
            let take = rest.len().min(254);
            out.push(take as u8 + 1);
            out.extend_from_slice(&rest[..take]);
            rest = &rest[take..];
            if take < 254 {
                break;
            }
        }
    }
    out.push(0);
    out
}

#[test]
fn golden_triangles() {
    // Short form: corner (1, 2, 3) um, deltas (+1, 0, 0) and (0, +1, -1).
    let t = Triangle { v: [Point3::new(1, 2, 3), Point3::new(2, 2, 3), Point3::new(1, 3, 2)] };
    let mut b = [0u8; 24];
    assert_eq!(encode_triangle(&t, &mut b).unwrap(), 20);
    assert_eq!(b[..20], GOLDEN_SHORT);
    // Long form: an edge of 100 mm.
    let t =
        Triangle { v: [Point3::new(0, 0, 0), Point3::new(100_000, 0, 0), Point3::new(0, 1, 0)] };
    assert_eq!(encode_triangle(&t, &mut b).unwrap(), 24);
    assert_eq!(b, GOLDEN_LONG);
}

// Bit 0 form 0; x = 1 at bit 1; y = 2 at bit 22; z = 3 at bits 41-42; then 16-bit deltas.
const GOLDEN_SHORT: [u8; 20] = [2, 0, 64, 0, 0, 6, 0, 32, 0, 0, 0, 0, 0, 0, 0, 32, 0, 224, 255, 31];
// Bit 0 form 1; corner 0 all zero; 21-bit deltas: x = 100000 at bit 61 (bytes 8, 9), then the
// second corner's y = 1 at bit 145.
const GOLDEN_LONG: [u8; 24] =
    [1, 0, 0, 0, 0, 0, 0, 0, 212, 48, 0, 0, 0, 0, 0, 0, 0, 0, 2, 0, 0, 0, 0, 0];

/// The job of the golden and round-trip tests: the default settings but a 0.16 mm layer and
/// 35 % infill; outer perimeter first, nearest seams, two skirt loops 4 mm out, 11 brim loops.
fn sample_job() -> JobSpec {
    let mut settings = PrintSettings::default();
    settings.layer_height_um = 160;
    settings.infill_percent = 35;
    JobSpec {
        settings,
        options: JobOptions {
            outer_perimeter_last: false,
            seam: 1,
            skirt_loops: 2,
            skirt_distance_um: 4000,
            brim_loops: 11,
        },
        model_height_um: 48_000,
        triangles: 225_154,
    }
}

#[test]
fn golden_job_start() {
    let mut buf = [0u8; MAX_PAYLOAD];
    let n = Message::JobStart(sample_job()).encode(&mut buf).unwrap();
    assert_eq!(&buf[..n], &GOLDEN_JOB_START);
    assert_eq!(Message::decode(&GOLDEN_JOB_START).unwrap(), Message::JobStart(sample_job()));
}

// Type 0x10, then little-endian: layer 160, first layer 200, line width 450 (i32 each),
// perimeters 2, infill 35, pattern 1 (zigzag), top 4, bottom 4 (u8 each), hotend 200, bed 60
// (u16), speeds 45, 60, 150, 20 mm/s (U32F32 bits: the whole mm/s in the high word),
// retraction 5000 um (i32) at 45 mm/s, minimum loop area 10,000 um^2 (u64); the options:
// outer perimeter last 0, seam 1, skirt loops 2 (u8 each), skirt distance 4000, brim loops 11
// (i32 each); model height 48,000 um (i32), triangles 225,154 (u32): 93 bytes.
#[rustfmt::skip]
const GOLDEN_JOB_START: [u8; 93] = [
    0x10,
    160, 0, 0, 0,  200, 0, 0, 0,  0xc2, 0x01, 0, 0,
    2, 35, 1, 4, 4,
    200, 0,  60, 0,
    0, 0, 0, 0, 45, 0, 0, 0,  0, 0, 0, 0, 60, 0, 0, 0,
    0, 0, 0, 0, 150, 0, 0, 0,  0, 0, 0, 0, 20, 0, 0, 0,
    0x88, 0x13, 0, 0,  0, 0, 0, 0, 45, 0, 0, 0,
    0x10, 0x27, 0, 0, 0, 0, 0, 0,
    0, 1, 2,  0xa0, 0x0f, 0, 0,  11, 0, 0, 0,
    0x80, 0xbb, 0, 0,  0x82, 0x6f, 0x03, 0,
];

fn all_messages() -> Vec<Vec<u8>> {
    let job = sample_job();
    let caps = SAMPLE_CAPS;
    let status = Status {
        state: DeviceState::Failed,
        layer: 12,
        layers: 240,
        planned_ms: 123_456,
        done_ms: 120_000,
        triangles: 5000,
        queue_fill_pct: 37,
        error: ErrorCode::Toolpath,
        detail: 12,
        hotend_c_x10: 2004,
        bed_c_x10: -12,
        heating: true,
    };
    let mut bb = BatchBuilder::new();
    bb.push(&Triangle { v: [Point3::new(5, 6, 7), Point3::new(8, 9, 10), Point3::new(5, 6, 900)] })
        .unwrap();
    bb.push(&Triangle {
        v: [Point3::new(0, 0, 0), Point3::new(200_000, 0, 0), Point3::new(0, 200_000, 250_000)],
    })
    .unwrap();
    let msgs = [
        Message::Hello { version: 1 },
        Message::Capabilities { version: 1, capacities: caps },
        Message::JobStart(job),
        Message::EndOfModel,
        Message::Pause,
        Message::Resume,
        Message::Abort,
        Message::EmergencyStop,
        Message::Status(status),
        Message::LayerDone { layer: 7, hash: 0x0123_4567_89ab_cdef },
    ];
    let mut out: Vec<Vec<u8>> = msgs
        .iter()
        .map(|m| {
            let mut b = [0u8; MAX_PAYLOAD];
            let n = m.encode(&mut b).unwrap();
            b[..n].to_vec()
        })
        .collect();
    out.push(bb.payload().to_vec());
    out
}

#[test]
fn every_message_round_trips() {
    for bytes in all_messages() {
        let m = Message::decode(&bytes).unwrap();
        let mut again = [0u8; MAX_PAYLOAD];
        let n = m.encode(&mut again).unwrap();
        assert_eq!(&again[..n], &bytes[..], "{m:?}");
        // Every truncation and every extension is refused.
        for cut in 0..bytes.len() {
            assert!(Message::decode(&bytes[..cut]).is_err(), "{m:?} cut at {cut}");
        }
        let mut longer = bytes.clone();
        longer.push(0);
        assert!(Message::decode(&longer).is_err(), "{m:?} extended");
    }
}

#[test]
fn batch_triangles_come_back_in_order() {
    let bytes = all_messages().pop().unwrap();
    let Message::Triangles(b) = Message::decode(&bytes).unwrap() else { panic!() };
    let tris: Vec<Triangle> = b.iter().collect();
    assert_eq!(tris.len(), 2);
    assert_eq!(tris[1].v[2], Point3::new(0, 200_000, 250_000));
    assert_eq!(bytes.len(), 2 + 20 + 24);
}

#[test]
fn decoder_resynchronises_and_refuses_corruption() {
    let good = wire(FrameType::Data, 1, 2, 3, b"payload");
    // Garbage, a frame, a truncated frame, a frame.
    let mut stream = vec![0x55, 0x13, 0x00];
    stream.extend_from_slice(&good);
    stream.extend_from_slice(&good[..5]);
    stream.push(0);
    stream.extend_from_slice(&good);
    let r = decode_all(&stream);
    let ok: Vec<_> = r.iter().filter_map(|x| x.as_ref().ok()).collect();
    assert_eq!(ok.len(), 2);
    assert_eq!(ok[0].4, b"payload");
    assert_eq!(r.iter().filter(|x| x.is_err()).count(), 2);
    // Every single-bit flip of the frame is refused (CRC-32 detects all of them).
    for i in 0..good.len() - 1 {
        for bit in 0..8 {
            let mut bad = good.clone();
            bad[i] ^= 1 << bit;
            let r = decode_all(&bad);
            assert!(r.iter().all(|x| x.is_err()), "flip {i}.{bit} accepted: {r:?}");
        }
    }
}

#[test]
fn wire_bytes_per_triangle() {
    // A full batch of short-form triangles: 19 x 20 bytes.
    let mut bb = BatchBuilder::new();
    let t = Triangle {
        v: [Point3::new(1000, 1000, 0), Point3::new(2000, 1000, 0), Point3::new(1000, 2000, 300)],
    };
    while bb.push(&t).is_ok() {}
    let n = bb.len();
    let w = frame::wire_len(bb.payload());
    let per = w as f64 / n as f64;
    eprintln!("{n} short triangles per frame, {w} wire bytes, {per:.2} bytes per triangle");
    assert_eq!(n, 19);
    assert!(per <= 21.0, "{per}");
}

fn coord() -> impl Strategy<Value = i32> {
    0..=strata::protocol::msg::MAX_WIRE_COORD_UM
}

proptest! {
    #[test]
    fn triangles_round_trip(c in proptest::array::uniform9(coord()), near in any::<bool>()) {
        let mut c = c;
        if near {
            for k in 3..9 {
                c[k] = (c[k % 3] + (c[k] % 60_000) - 30_000).clamp(0, (1 << 20) - 1);
            }
        }
        let t = Triangle { v: [
            Point3::new(c[0], c[1], c[2]), Point3::new(c[3], c[4], c[5]), Point3::new(c[6], c[7], c[8])] };
        let mut b = [0u8; 24];
        let n = encode_triangle(&t, &mut b).unwrap();
        let (back, m) = decode_triangle(&b[..n]).unwrap();
        prop_assert_eq!(back, t);
        prop_assert_eq!(m, n);
    }

    #[test]
    fn decoding_noise_never_panics(bytes in proptest::collection::vec(any::<u8>(), 0..1200)) {
        let _ = decode_all(&bytes);
        let _ = Message::decode(&bytes);
    }

    #[test]
    fn frames_round_trip(seq: u8, ack: u8, credits: u8,
                         payload in proptest::collection::vec(any::<u8>(), 0..=MAX_PAYLOAD)) {
        let w = wire(FrameType::Data, seq, ack, credits, &payload);
        prop_assert!(w.len() <= MAX_WIRE);
        prop_assert_eq!(w.iter().filter(|&&b| b == 0).count(), 1);
        let r = decode_all(&w);
        prop_assert_eq!(r, vec![Ok((FrameType::Data, seq, ack, credits, payload))]);
    }
}

#[test]
fn golden_status_with_temperatures() {
    let s = Status {
        state: DeviceState::Failed,
        layer: 3,
        layers: 50,
        planned_ms: 1000,
        done_ms: 900,
        triangles: 12,
        queue_fill_pct: 25,
        error: ErrorCode::Thermal,
        detail: 10,
        hotend_c_x10: 2004,
        bed_c_x10: -12,
        heating: false,
    };
    let mut buf = [0u8; MAX_PAYLOAD];
    let n = Message::Status(s).encode(&mut buf).unwrap();
    // Type 0x30, state 4, then little-endian layer, layers, planned, done, triangles (u32),
    // fill 25, error 9 (Thermal), detail 10 (u32), hotend 2004 and bed -12 (i16), heating 0.
    #[rustfmt::skip]
    let golden: [u8; 33] = [
        0x30, 4,
        3, 0, 0, 0,  50, 0, 0, 0,  0xe8, 0x03, 0, 0,  0x84, 0x03, 0, 0,  12, 0, 0, 0,
        25, 9,  10, 0, 0, 0,
        0xd4, 0x07,  0xf4, 0xff,  0,
    ];
    assert_eq!(&buf[..n], &golden);
    assert_eq!(Message::decode(&golden).unwrap(), Message::Status(s));
    // A heating flag other than 0 or 1 is refused.
    let mut bad = golden;
    bad[32] = 2;
    assert!(Message::decode(&bad).is_err());
}

#[test]
fn golden_job_report() {
    let j = strata::protocol::JobReport {
        steps: [1, 2, 3, 0x1_0000_0000],
        positions: [5, -1, 0, 7],
        print_ticks: 72_000_000,
    };
    let mut buf = [0u8; MAX_PAYLOAD];
    let n = Message::JobReport(j).encode(&mut buf).unwrap();
    // Type 0x32, then nine little-endian u64: steps X Y Z E, positions (two's complement), ticks.
    let mut golden = vec![0x32];
    for v in [1u64, 2, 3, 1 << 32, 5, u64::MAX, 0, 7, 72_000_000] {
        golden.extend_from_slice(&v.to_le_bytes());
    }
    assert_eq!(&buf[..n], &golden[..]);
    assert_eq!(Message::decode(&golden).unwrap(), Message::JobReport(j));
    assert!(Message::decode(&golden[..golden.len() - 1]).is_err());
}

/// The failure in words: its type byte, then the text as UTF-8 to the payload's end (so any
/// shorter text is a message too, unlike the fixed-size messages above); bytes that are not
/// UTF-8 are refused.
#[test]
fn golden_failure_words() {
    let text = "slicer: too many active triangles in layer 37 (capacity 388) \u{b0}";
    let mut b = [0u8; MAX_PAYLOAD];
    let n = Message::Failure(text).encode(&mut b).unwrap();
    assert_eq!(b[0], 0x33);
    assert_eq!(&b[1..n], text.as_bytes());
    assert_eq!(Message::decode(&b[..n]).unwrap(), Message::Failure(text));
    assert_eq!(Message::decode(&[0x33]).unwrap(), Message::Failure(""));
    // The degree sign is two bytes: cut between them, the text is not UTF-8.
    assert!(Message::decode(&b[..n - 1]).is_err());
    assert!(Message::decode(&[0x33, 0xff, b'a']).is_err());
    // A text longer than a payload does not encode.
    let long = "x".repeat(MAX_PAYLOAD);
    assert!(Message::Failure(&long).encode(&mut b).is_err());
}

/// A G-code job: its start (type 0x13, then the text's bytes and layers as little-endian u32),
/// its text (type 0x14, then the bytes to the payload's end; at least one).
#[test]
fn golden_gcode_messages() {
    let spec = GcodeSpec { bytes: 436_313, layers: 100 };
    let mut b = [0u8; MAX_PAYLOAD];
    let n = Message::GcodeStart(spec).encode(&mut b).unwrap();
    // 436,313 = 0x0006_A859.
    assert_eq!(&b[..n], &[0x13, 0x59, 0xa8, 0x06, 0x00, 100, 0, 0, 0]);
    assert_eq!(Message::decode(&b[..n]).unwrap(), Message::GcodeStart(spec));
    for cut in 0..n {
        assert!(Message::decode(&b[..cut]).is_err());
    }
    let text = b"G1 X10 Y2";
    let n = Message::Gcode(text).encode(&mut b).unwrap();
    assert_eq!(b[0], 0x14);
    assert_eq!(&b[1..n], text);
    assert_eq!(Message::decode(&b[..n]).unwrap(), Message::Gcode(text));
    // No text is no message; a frame's worth is the most.
    assert!(Message::decode(&[0x14]).is_err());
    assert!(Message::Gcode(b"").encode(&mut b).is_err());
    let full = vec![b'G'; MAX_PAYLOAD - 1];
    assert_eq!(Message::Gcode(&full).encode(&mut b), Ok(MAX_PAYLOAD));
    assert!(Message::Gcode(&[b'G'; MAX_PAYLOAD]).encode(&mut b).is_err());
}

#[test]
fn golden_parked() {
    let parked = ParkedJob { layer: 41, taken: 1234, fingerprint: 0xdead_beef };
    let mut buf = [0u8; MAX_PAYLOAD];
    let n = Message::Parked(parked).encode(&mut buf).unwrap();
    // Type 0x34, then layer, triangles taken and fingerprint, u32 little-endian each.
    let golden = [0x34, 41, 0, 0, 0, 0xd2, 0x04, 0, 0, 0xef, 0xbe, 0xad, 0xde];
    assert_eq!(&buf[..n], &golden);
    assert_eq!(Message::decode(&golden), Ok(Message::Parked(parked)));
    assert!(Message::decode(&golden[..12]).is_err());
    // A job's fingerprint is the CRC-32 of its start message (Python: zlib.crc32).
    assert_eq!(job_fingerprint(&[0x10, 1, 2, 3]), 0xdba0_d18c);
}

#[test]
fn golden_card_messages() {
    use strata::protocol::{CardEntry, CardFault};
    let entry = CardEntry { size: 0x0001_2345, is_dir: false, name: "cube.gcode" };
    let mut with_name = vec![0x41, 0x45, 0x23, 0x01, 0x00, 0];
    with_name.extend_from_slice(b"cube.gcode");
    let mut print = vec![0x43];
    print.extend_from_slice("würfel.gcode".as_bytes());
    // Type byte, then little-endian fields; names are the rest of the payload, UTF-8.
    let cases: [(Message<'_>, Vec<u8>); 13] = [
        (Message::CardRemove("a.g"), vec![0x46, b'a', b'.', b'g']),
        (Message::CardCreate("a.g"), vec![0x47, b'a', b'.', b'g']),
        (Message::CardData(&[0, 1, 0xff]), vec![0x48, 0, 1, 0xff]),
        (Message::CardClose, vec![0x49]),
        (Message::CardDone { bytes: 513 }, vec![0x4A, 0x01, 0x02, 0, 0]),
        (Message::CardList { from: 0x0102 }, vec![0x40, 0x02, 0x01]),
        (Message::CardEntry(entry), with_name),
        (Message::CardListed { next: 7, done: true }, vec![0x42, 7, 0, 1]),
        (Message::CardPrint("würfel.gcode"), print),
        (Message::CardRefused(CardFault::Stl), vec![0x44, 9]),
        (Message::CardRefused(CardFault::BadJob), vec![0x44, 15]),
        (Message::CardRefused(CardFault::TooComplex), vec![0x44, 20]),
        (Message::CardStarted { bytes: 436_000 }, vec![0x45, 0x20, 0xa7, 0x06, 0x00]),
    ];
    for (m, golden) in cases {
        let mut buf = [0u8; MAX_PAYLOAD];
        let n = m.encode(&mut buf).unwrap();
        assert_eq!(&buf[..n], &golden[..], "{m:?}");
        assert_eq!(Message::decode(&golden), Ok(m));
    }
    // Refused: an unknown fault, a flag not 0/1, a name not UTF-8, an empty name, short fields.
    for bad in [
        &[0x44, 0][..],
        &[0x44, 21],
        &[0x42, 7, 0, 2],
        &[0x43, 0xff, 0xfe],
        &[0x43],
        &[0x40, 1],
        &[0x41, 1, 0, 0, 0],
        &[0x45, 1, 2, 3],
        &[0x46],
        &[0x47],
        &[0x48],
        &[0x49, 0],
        &[0x4A, 1, 2, 3],
    ] {
        assert!(Message::decode(bad).is_err(), "{bad:?}");
    }
    assert!(Message::CardPrint("").encode(&mut [0u8; 8]).is_err());
    assert!(Message::CardCreate("").encode(&mut [0u8; 8]).is_err());
    assert!(Message::CardData(&[]).encode(&mut [0u8; 8]).is_err());
}
