//! Fuzz target for the protocol's receive path: `strata::protocol::Decoder` (frames) and
//! `Message::decode` (payloads), and a device-side `Endpoint` fed the same bytes.
//!
//! Checks: no panic; every frame the decoder accepts re-encodes to a wire frame that decodes
//! to the same frame (so it passed length, CRC, version and type checks); every payload that
//! decodes as a message re-encodes to the same bytes (no field is accepted loosely), and a
//! triangle batch yields exactly its count of triangles; the endpoint delivers only payloads
//! of accepted frames.
#![no_main]

use libfuzzer_sys::fuzz_target;
use strata::protocol::frame;
use strata::protocol::{Decoder, Endpoint, LinkConfig, Message, MAX_PAYLOAD, MAX_WIRE};

fuzz_target!(|data: &[u8]| {
    let mut d = Decoder::new();
    let mut accepted: Vec<Vec<u8>> = Vec::new();
    for &b in data {
        if let Some(Ok(f)) = d.push(b) {
            let mut out = [0u8; MAX_WIRE];
            let n = frame::encode(f.kind, f.seq, f.ack, f.credits, f.payload, &mut out)
                .expect("an accepted frame re-encodes");
            let mut d2 = Decoder::new();
            let (last, body) = out[..n].split_last().expect("not empty");
            for &b in body {
                assert!(d2.push(b).is_none());
            }
            let again = d2.push(*last).expect("one frame");
            assert_eq!(again.expect("re-encoded frame decodes"), f);
            accepted.push(f.payload.to_vec());
            check_message(f.payload);
        }
    }
    check_message(data);

    let mut ep: Endpoint<2, 4> = Endpoint::new(LinkConfig::default());
    ep.receive(data, 1);
    for i in 0..ep.rx_len() {
        let p = ep.get(i).expect("delivered");
        assert!(accepted.iter().any(|a| a.as_slice() == p), "delivered a payload never accepted");
    }
    let mut out = [0u8; MAX_WIRE];
    while ep.poll_transmit(2, &mut out) != 0 {}
});

fn check_message(bytes: &[u8]) {
    if let Ok(m) = Message::decode(bytes) {
        // Raw inputs may be longer than a frame's payload.
        let mut out = vec![0u8; bytes.len().max(MAX_PAYLOAD)];
        let n = m.encode(&mut out).expect("a decoded message re-encodes");
        assert_eq!(&out[..n], bytes);
        if let Message::Triangles(b) = m {
            assert_eq!(b.iter().count(), b.len());
        }
    }
}
