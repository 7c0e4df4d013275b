//! Fuzz target for the protocol's receive path: `strata::protocol::Decoder` (frames) and
//! `Message::decode` (payloads), and the firmware's `Endpoint` fed the same bytes.
//!
//! Checks: no panic; every frame the decoder accepts re-encodes to a wire frame that decodes
//! to the same frame (so it passed length, CRC, version and type checks); every payload that
//! decodes as a message re-encodes to the same bytes (no field is accepted loosely), and a
//! triangle batch yields exactly its count of triangles; the endpoint delivers only payloads
//! of accepted frames, before and after a session change, and so does a host's opening one.
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

    // The firmware's endpoint (one receive slot, the device's timers) with a message of its
    // own in flight: the bytes in two halves, 250 ms apart, transmitting around them (the
    // retransmission timer expires, the peer is heard or not: probes and resends).
    let mut ep: Endpoint<2, 1> = Endpoint::new(LinkConfig::device());
    let mut out = [0u8; MAX_WIRE];
    let _ = ep.send(b"status");
    while ep.poll_transmit(0, &mut out) != 0 {}
    let (first, second) = data.split_at(data.len() / 2);
    for (bytes, at) in [(first, 1), (second, 250)] {
        while ep.poll_transmit(at - 1, &mut out) != 0 {}
        ep.receive(bytes, at);
        for i in 0..ep.rx_len() {
            let p = ep.get(i).expect("delivered");
            assert!(accepted.iter().any(|a| a.as_slice() == p), "delivered a payload never accepted");
        }
        while ep.poll_transmit(at + 120, &mut out) != 0 {}
    }

    // A host's endpoint opening a session, fed the same bytes: it sends no data before the
    // device echoed its nonce, and delivers only accepted payloads.
    let mut host: Endpoint<2, 1> = Endpoint::new(LinkConfig::default());
    host.open(0x1234);
    let _ = host.send(b"hello");
    host.receive(data, 1);
    while host.poll_transmit(2, &mut out) != 0 {}
    for i in 0..host.rx_len() {
        let p = host.get(i).expect("delivered");
        assert!(accepted.iter().any(|a| a.as_slice() == p), "delivered a payload never accepted");
    }
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
