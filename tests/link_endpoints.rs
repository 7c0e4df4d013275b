//! Two protocol endpoints over a seeded lossy byte channel (drop, corrupt, duplicate,
//! truncate, delay frames): every message arrives exactly once, in order and unchanged; the
//! sender never exceeds the receiver's credits; a dead link is reported within bounded time.

use strata::protocol::{Endpoint, FrameType, LinkConfig, LinkError, MAX_PAYLOAD, MAX_WIRE};
use strata_testkit::rng::Rng;

/// One direction: whole frames with a delivery time; faults applied per frame.
struct Channel {
    rng: Rng,
    loss: u64,
    queue: Vec<(u32, Vec<u8>)>,
    cut: bool,
}

impl Channel {
    fn send(&mut self, now: u32, frame: &[u8]) {
        if self.cut || self.rng.per_mille(self.loss) {
            return;
        }
        let mut f = frame.to_vec();
        if self.rng.per_mille(self.loss) {
            let i = self.rng.below(f.len() as u64) as usize;
            f[i] ^= 1 << self.rng.below(8);
        }
        if self.rng.per_mille(self.loss) {
            f.truncate(self.rng.below(f.len() as u64) as usize);
        }
        let delay = if self.rng.per_mille(self.loss) { 1 + self.rng.below(40) as u32 } else { 1 };
        if self.rng.per_mille(self.loss) {
            self.queue.push((now + delay, f.clone()));
        }
        self.queue.push((now + delay, f));
    }
    fn take(&mut self, now: u32) -> Vec<u8> {
        let mut out = Vec::new();
        self.queue.retain(|(at, f)| {
            if *at <= now {
                out.extend_from_slice(f);
                false
            } else {
                true
            }
        });
        out
    }
}

fn payload(i: u32) -> Vec<u8> {
    let len = (i as usize * 37) % MAX_PAYLOAD + 1;
    (0..len).map(|k| (i as usize * 31 + k * 7) as u8).collect()
}

struct Run {
    delivered: u32,
    a: strata::protocol::LinkStats,
    b: strata::protocol::LinkStats,
    end_ms: u32,
    error: Option<LinkError>,
}

/// Sends `count` messages from A (8 slots, the host's timers) to B (4 slots, the device's
/// timers, the application takes one every other millisecond) over channels with `loss` per
/// mille of each fault.
fn transfer(count: u32, loss: u64, seed: u64, cut_at: Option<u32>) -> Run {
    let mut a: Endpoint<8, 8> = Endpoint::new(LinkConfig::default());
    let mut b: Endpoint<4, 4> = Endpoint::new(LinkConfig::device());
    let mut ab = Channel { rng: Rng::new(seed), loss, queue: Vec::new(), cut: false };
    let mut ba = Channel { rng: Rng::new(seed ^ 0xdead_beef), loss, queue: Vec::new(), cut: false };
    let mut frame = [0u8; MAX_WIRE];
    let (mut sent, mut got) = (0u32, 0u32);
    let mut now = 0u32;
    let mut error = None;
    while got < count && now < 600_000 {
        now += 1;
        if cut_at.is_some_and(|c| now >= c) {
            ab.cut = true;
            ba.cut = true;
        }
        a.receive(&ba.take(now), now);
        b.receive(&ab.take(now), now);
        if let Err(e) = a.check(now) {
            error = Some(e);
            break;
        }
        while sent < count && a.send(&payload(sent)).is_ok() {
            sent += 1;
        }
        if now % 2 == 0 {
            if let Some(p) = b.peek() {
                assert_eq!(p, &payload(got)[..], "message {got} altered or out of order");
                got += 1;
                b.pop();
            }
        }
        loop {
            let n = a.poll_transmit(now, &mut frame);
            if n == 0 {
                break;
            }
            ab.send(now, &frame[..n]);
        }
        loop {
            let n = b.poll_transmit(now, &mut frame);
            if n == 0 {
                break;
            }
            ba.send(now, &frame[..n]);
        }
    }
    Run { delivered: got, a: *a.stats(), b: *b.stats(), end_ms: now, error }
}

#[test]
fn clean_link_respects_credits() {
    let r = transfer(2_000, 0, 1, None);
    assert_eq!(r.delivered, 2_000);
    assert_eq!(r.a.retransmits, 0);
    assert_eq!(r.b.no_room, 0, "A sent beyond B's credits");
    assert_eq!(r.b.duplicates + r.b.out_of_order + r.b.bad_frames, 0);
}

#[test]
fn lossy_links_deliver_everything_once_in_order() {
    for (loss, seed) in [(10, 1), (50, 2), (50, 3), (100, 4), (200, 5)] {
        let r = transfer(1_000, loss, seed, None);
        eprintln!("loss {loss}/1000: {} ms, A {:?}, B {:?}", r.end_ms, r.a, r.b);
        assert_eq!(r.delivered, 1_000, "loss {loss}: {:?}", r.error);
        assert!(r.b.bad_frames > 0 && r.a.retransmits > 0);
        assert_eq!(r.b.delivered, 1_000);
    }
}

#[test]
fn dead_link_is_reported_in_bounded_time() {
    let r = transfer(100_000, 0, 1, Some(500));
    let e = r.error.expect("no error");
    assert!(matches!(e, LinkError::Dead { silent_ms } if silent_ms >= 3000));
    assert!(r.end_ms <= 500 + 3_001, "{}", r.end_ms);
    eprintln!("{e} at {} ms", r.end_ms);
}

/// Bytes the Creality board buffers for a busy thread mode (`RX_RING` in
/// `firmware/src/board/creality.rs`: a 512-slot heapless queue holds 511).
const DEVICE_RX_RING: usize = 511;

/// The host (8 slots, its timers) streams full messages ([`MAX_PAYLOAD`] bytes) to the
/// firmware's endpoint (2 transmit slots, 1 receive slot, the device's timers) on a clean
/// link at 250000 baud; the device's thread
/// mode stops reading for `busy_ms` every other second (a large layer's computation): the
/// bytes that arrive meanwhile wait in a ring of [`DEVICE_RX_RING`] bytes. None may be lost
/// to a full ring, and every message arrives. Returns the ring's highest fill.
fn busy_device(busy_ms: u32) -> usize {
    const COUNT: u32 = 200;
    let full =
        |i: u32| -> Vec<u8> { (0..MAX_PAYLOAD).map(|k| (i as usize * 31 + k) as u8).collect() };
    // 250000 baud: 25 bytes a millisecond.
    const BYTES_PER_MS: usize = 25;
    let mut host: Endpoint<8, 8> = Endpoint::new(LinkConfig::default());
    let mut dev: Endpoint<2, 1> = Endpoint::new(LinkConfig::device());
    let (mut wire_in, mut ring, mut wire_out) = (Vec::new(), Vec::new(), Vec::new());
    let (mut sent, mut got, mut fill_max, mut dropped) = (0u32, 0u32, 0usize, 0usize);
    let mut frame = [0u8; MAX_WIRE];
    let mut now = 0u32;
    while got < COUNT && now < 600_000 {
        now += 1;
        // The UART: 25 bytes a millisecond each way; the device's interrupt fills the ring.
        for b in wire_in.drain(..wire_in.len().min(BYTES_PER_MS)) {
            if ring.len() < DEVICE_RX_RING {
                ring.push(b);
            } else {
                dropped += 1;
            }
        }
        fill_max = fill_max.max(ring.len());
        let back: Vec<u8> = wire_out.drain(..wire_out.len().min(BYTES_PER_MS)).collect();
        host.receive(&back, now);
        assert!(host.check(now).is_ok(), "the host gave the busy device up at {now} ms");
        while sent < COUNT && host.send(&full(sent)).is_ok() {
            sent += 1;
        }
        loop {
            let n = host.poll_transmit(now, &mut frame);
            if n == 0 {
                break;
            }
            wire_in.extend_from_slice(&frame[..n]);
        }
        // Thread mode: busy for `busy_ms` out of every 2 s, else a turn a millisecond.
        if now % 2000 < busy_ms {
            continue;
        }
        dev.receive(&std::mem::take(&mut ring), now);
        if let Some(p) = dev.peek() {
            assert_eq!(p, &full(got)[..], "message {got} altered or out of order");
            got += 1;
            dev.pop();
        }
        loop {
            let n = dev.poll_transmit(now, &mut frame);
            if n == 0 {
                break;
            }
            wire_out.extend_from_slice(&frame[..n]);
        }
    }
    assert_eq!(dropped, 0, "{busy_ms} ms busy: {dropped} bytes lost to a full ring");
    assert_eq!(got, COUNT, "{busy_ms} ms busy: not every message arrived");
    fill_max
}

#[test]
fn a_busy_device_buffers_no_more_than_its_receive_ring() {
    for busy_ms in [50, 430, 1000, 1900] {
        let fill = busy_device(busy_ms);
        eprintln!("thread mode busy {busy_ms} ms: the ring held at most {fill} B");
    }
}

/// Every frame `from` has due at `now` into `to`.
fn pass<const A: usize, const B: usize, const C: usize, const D: usize>(
    from: &mut Endpoint<A, B>,
    to: &mut Endpoint<C, D>,
    now: u32,
) {
    let mut frame = [0u8; MAX_WIRE];
    loop {
        let n = from.poll_transmit(now, &mut frame);
        if n == 0 {
            break;
        }
        to.receive(&frame[..n], now);
    }
}

/// Both ways for `ms` milliseconds from `*now` on, the device's application taking nothing.
fn exchange(host: &mut Endpoint<8, 8>, dev: &mut Endpoint<4, 4>, now: &mut u32, ms: u32) {
    for _ in 0..ms {
        *now += 1;
        pass(host, dev, *now);
        pass(dev, host, *now);
    }
}

/// A host that died mid-session leaves the device's sequence numbers where they were; a new
/// host opens its own session (a new nonce) and talks at once, without waiting for the
/// device to notice the silence. Nothing of the old session crosses into the new one.
#[test]
fn a_new_host_opens_a_session_on_a_device_whose_last_host_died() {
    let mut dev: Endpoint<4, 4> = Endpoint::new(LinkConfig::device());
    let mut old: Endpoint<8, 8> = Endpoint::new(LinkConfig::default());
    let mut now = 0;
    old.open(7);
    for m in [&b"one"[..], b"two", b"three"] {
        old.send(m).unwrap();
    }
    exchange(&mut old, &mut dev, &mut now, 20);
    assert!(old.is_open() && old.all_acked());
    for want in [&b"one"[..], b"two", b"three"] {
        assert_eq!(dev.peek(), Some(want));
        dev.pop();
    }
    // The old host dies; the device queues answers it will never have acknowledged.
    dev.send(b"stale").unwrap();
    let mut new: Endpoint<8, 8> = Endpoint::new(LinkConfig::default());
    new.open(9);
    new.send(b"hello").unwrap();
    exchange(&mut new, &mut dev, &mut now, 5);
    assert!(new.is_open());
    assert_eq!(dev.peek(), Some(&b"hello"[..]));
    dev.pop();
    dev.send(b"answer").unwrap();
    exchange(&mut new, &mut dev, &mut now, 5);
    assert_eq!(new.peek(), Some(&b"answer"[..]), "the old session's message crossed over");
    new.pop();
    assert_eq!(new.peek(), None);
    // A stale duplicate of the new session's `Open` changes nothing.
    let mut frame = [0u8; MAX_WIRE];
    let n = strata::protocol::frame::encode(FrameType::Open, 9, 0, 8, &[], &mut frame).unwrap();
    dev.receive(&frame[..n], now);
    new.send(b"more").unwrap();
    exchange(&mut new, &mut dev, &mut now, 5);
    assert_eq!(dev.peek(), Some(&b"more"[..]));
}

/// A new session drops what the old one left untaken: the new host's first message is the
/// first the application sees.
#[test]
fn a_new_session_drops_what_the_old_one_left() {
    let mut dev: Endpoint<4, 4> = Endpoint::new(LinkConfig::device());
    let mut old: Endpoint<8, 8> = Endpoint::new(LinkConfig::default());
    let mut now = 0;
    old.open(3);
    old.send(b"last batch").unwrap();
    exchange(&mut old, &mut dev, &mut now, 10);
    assert_eq!((dev.peek(), dev.session()), (Some(&b"last batch"[..]), 3));
    let mut new: Endpoint<8, 8> = Endpoint::new(LinkConfig::default());
    new.open(4);
    new.send(b"hello").unwrap();
    exchange(&mut new, &mut dev, &mut now, 5);
    assert!(new.is_open());
    assert_eq!((dev.peek(), dev.session()), (Some(&b"hello"[..]), 4));
}

/// The opening handshake survives a lossy link: every message of the new session arrives
/// once, in order.
#[test]
fn a_session_opens_over_a_lossy_link() {
    for seed in 1..=20u64 {
        let mut dev: Endpoint<4, 4> = Endpoint::new(LinkConfig::device());
        let mut host: Endpoint<8, 8> = Endpoint::new(LinkConfig::default());
        host.open(seed as u16);
        let mut hd = Channel { rng: Rng::new(seed), loss: 100, queue: Vec::new(), cut: false };
        let mut dh = Channel { rng: Rng::new(!seed), loss: 100, queue: Vec::new(), cut: false };
        let mut frame = [0u8; MAX_WIRE];
        let (mut sent, mut got, mut now) = (0u32, 0u32, 0u32);
        while got < 50 && now < 100_000 {
            now += 1;
            host.receive(&dh.take(now), now);
            dev.receive(&hd.take(now), now);
            while sent < 50 && host.send(&payload(sent)).is_ok() {
                sent += 1;
            }
            if let Some(p) = dev.peek() {
                assert_eq!(p, &payload(got)[..], "seed {seed}: message {got}");
                dev.pop();
                got += 1;
            }
            loop {
                let n = host.poll_transmit(now, &mut frame);
                if n == 0 {
                    break;
                }
                hd.send(now, &frame[..n]);
            }
            loop {
                let n = dev.poll_transmit(now, &mut frame);
                if n == 0 {
                    break;
                }
                dh.send(now, &frame[..n]);
            }
        }
        assert_eq!(got, 50, "seed {seed}");
    }
}
