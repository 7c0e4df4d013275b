//! The reliable link: one [`Endpoint`] on each side (host and device, the same code).
//!
//! Data frames carry an 8-bit sequence number and are delivered to the application exactly
//! once and in order (go-back-N):
//! - the receiver accepts only the next expected sequence number, and only into a free
//!   receive slot; anything else (a duplicate, a frame after a lost one, no room) is dropped
//!   and answered with an ack;
//! - every frame carries a cumulative ack (the next sequence number expected) and the
//!   sender's free receive slots (credits): a peer sends sequence number `s` only while
//!   `s - ack < credits`, so the receive buffer never overflows;
//! - unacknowledged frames are sent again, all of them from the oldest, when no ack advanced
//!   for [`LinkConfig::retransmit_ms`] and the peer has been heard since (any valid frame
//!   at or after that point). Until it is, a **probe** goes out instead: an empty data frame
//!   with the sequence number before the window, which a live peer answers at once with an
//!   ack (a duplicate); the probes' interval doubles from `retransmit_ms` up to
//!   [`LinkConfig::keepalive_ms`] (a probe is a keepalive too). A silent peer is busy or gone, and resending to it would only fill its
//!   receive buffer: a peer that stops reading for a while (the device slicing a large
//!   layer) receives its credits' worth of data frames and then only probes and keepalives,
//!   [`PROBE_WIRE`] bytes each;
//! - an ack frame goes out when one is due and no data frame can carry it, and at least
//!   every [`LinkConfig::keepalive_ms`]; hearing nothing for [`LinkConfig::dead_ms`] makes
//!   the link [`LinkError::Dead`].
//!
//! - a host opens a **session** before its first data frame ([`Endpoint::open`]): it sends
//!   an [`FrameType::Open`] frame with a nonzero 16-bit nonce every [`LinkConfig::retransmit_ms`]
//!   until the device echoes it. A device that hears a new nonce starts afresh: sequence
//!   numbers from 0, and what the old session left queued either way is dropped (frames
//!   not acknowledged, messages the application had not taken: [`Endpoint::session`]
//!   tells it that a new session began). The same nonce again is only echoed. So a new
//!   host can talk at once to a device whose last host died mid-job, and a stale duplicate
//!   of an `Open` never cuts a running session.
//!
//! Time is an argument (`now_ms`, wrapping `u32`); nothing here reads a clock.

use super::frame::{self, Decoder, FrameType, MAX_PAYLOAD, MAX_WIRE};

/// Timers of an endpoint, milliseconds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub struct LinkConfig {
    /// Resend unacknowledged frames after this long without ack progress, once the peer is
    /// heard from after that.
    pub retransmit_ms: u32,
    /// Send an ack (with the current credits) at least this often.
    pub keepalive_ms: u32,
    /// The link is dead after this long without any valid frame from the peer.
    pub dead_ms: u32,
}

impl LinkConfig {
    /// The device's timers: the defaults with an ack at least every 100 ms, so that the host
    /// hears a live device often (its probes and resends wait for that, see the module docs)
    /// while the host's own keepalives, which a busy device buffers unread, stay at 250 ms.
    pub const fn device() -> Self {
        Self { retransmit_ms: 100, keepalive_ms: 100, dead_ms: 3000 }
    }
}

impl Default for LinkConfig {
    /// 100 ms retransmission (a full 16-triangle frame takes 17 ms at 250000 baud), 250 ms
    /// keepalive, 3 s to declare the link dead.
    fn default() -> Self {
        Self { retransmit_ms: 100, keepalive_ms: 250, dead_ms: 3000 }
    }
}

/// Why the link stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum LinkError {
    /// No valid frame from the peer for `silent_ms` (at least [`LinkConfig::dead_ms`]).
    Dead {
        /// How long the peer was silent.
        silent_ms: u32,
    },
}

impl core::fmt::Display for LinkError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Dead { silent_ms } => {
                write!(f, "link dead: no valid frame from the peer for {silent_ms} ms")
            }
        }
    }
}

/// Why [`Endpoint::send`] refused a message.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SendError {
    /// Every transmit slot holds an unacknowledged frame: poll and retry.
    Full,
    /// The payload is longer than [`MAX_PAYLOAD`].
    TooLong,
}

impl core::fmt::Display for SendError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Full => write!(f, "transmit window full"),
            Self::TooLong => write!(f, "payload longer than {MAX_PAYLOAD} bytes"),
        }
    }
}

/// Wire bytes of a probe or an ack (a frame with no payload).
pub const PROBE_WIRE: usize = frame::MIN_WIRE;

/// Counters of an endpoint.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LinkStats {
    /// Frames written (data, resent data and acks).
    pub frames_sent: u64,
    /// Bytes written.
    pub bytes_sent: u64,
    /// Data frames sent again.
    pub retransmits: u64,
    /// Probes sent to a silent peer (see the module docs).
    pub probes: u64,
    /// Valid frames received.
    pub frames_received: u64,
    /// Frames discarded by the decoder (CRC, COBS, length, version, type).
    pub bad_frames: u64,
    /// Data frames dropped as duplicates.
    pub duplicates: u64,
    /// Data frames dropped as out of order (after a lost one).
    pub out_of_order: u64,
    /// Data frames dropped for want of a free receive slot (the peer exceeded the credits).
    pub no_room: u64,
    /// Messages delivered to the application.
    pub delivered: u64,
}

#[derive(Debug, Clone, Copy)]
struct Slot {
    len: u16,
    buf: [u8; MAX_PAYLOAD],
}

const EMPTY: Slot = Slot { len: 0, buf: [0; MAX_PAYLOAD] };

impl Slot {
    fn bytes(&self) -> &[u8] {
        &self.buf[..self.len as usize]
    }
}

/// Queues `payload` (at most [`MAX_PAYLOAD`] bytes) after the `len` slots from `head` of a
/// ring of slots.
fn push<const N: usize>(
    ring: &mut [Slot; N],
    head: usize,
    len: &mut usize,
    payload: &[u8],
) -> Result<(), SendError> {
    if *len == N {
        return Err(SendError::Full);
    }
    let slot = &mut ring[(head + *len) % N];
    slot.buf[..payload.len()].copy_from_slice(payload);
    slot.len = payload.len() as u16;
    *len += 1;
    Ok(())
}

/// One end of the link with `TX` transmit slots (unacknowledged frames) and `RX` receive
/// slots (delivered, not yet taken by the application). `TX` and `RX` must be 1..=64.
#[derive(Debug, Clone)]
pub struct Endpoint<const TX: usize, const RX: usize> {
    cfg: LinkConfig,
    decoder: Decoder,
    tx: [Slot; TX],
    /// Slot index of the oldest queued frame.
    tx_head: usize,
    /// Queued frames (oldest at `tx_head`).
    tx_len: usize,
    /// Queued frames sent since the last (re)start of the window (the next to send).
    tx_sent: usize,
    /// Queued frames sent at least once (what an ack may cover).
    tx_ever: usize,
    /// Sequence number of the oldest queued frame.
    tx_base: u8,
    /// Peer's free slots as of its last frame (counted from `tx_base`).
    peer_credits: u8,
    /// Time the retransmission timer started (last ack progress or window restart).
    tx_timer_ms: u32,
    /// The last probe and the interval to the next one, ms.
    probe_ms: u32,
    probe_every_ms: u32,
    rx: [Slot; RX],
    rx_head: usize,
    rx_len: usize,
    /// Next sequence number expected.
    rx_next: u8,
    ack_due: bool,
    last_rx_ms: u32,
    last_tx_ms: u32,
    started: bool,
    /// The session's nonce (0: none opened).
    session: u16,
    /// This end opens sessions (a host: [`Endpoint::open`]); the other echoes them.
    opener: bool,
    /// A host: the session is not yet echoed (its `Open` frames go out, no data).
    opening: bool,
    /// A device: the session's `Open` is to be echoed.
    echo_due: bool,
    stats: LinkStats,
}

impl<const TX: usize, const RX: usize> Endpoint<TX, RX> {
    const OK: () = assert!(TX >= 1 && TX <= 64 && RX >= 1 && RX <= 64);

    /// A fresh endpoint (sequence numbers from 0; one frame may go out before the peer
    /// announced its credits).
    pub const fn new(cfg: LinkConfig) -> Self {
        let () = Self::OK;
        Self {
            cfg,
            decoder: Decoder::new(),
            tx: [EMPTY; TX],
            tx_head: 0,
            tx_len: 0,
            tx_sent: 0,
            tx_ever: 0,
            tx_base: 0,
            peer_credits: 1,
            tx_timer_ms: 0,
            probe_ms: 0,
            probe_every_ms: 0,
            rx: [EMPTY; RX],
            rx_head: 0,
            rx_len: 0,
            rx_next: 0,
            ack_due: false,
            last_rx_ms: 0,
            last_tx_ms: 0,
            started: false,
            session: 0,
            opener: false,
            opening: false,
            echo_due: false,
            stats: LinkStats {
                frames_sent: 0,
                bytes_sent: 0,
                retransmits: 0,
                probes: 0,
                frames_received: 0,
                bad_frames: 0,
                duplicates: 0,
                out_of_order: 0,
                no_room: 0,
                delivered: 0,
            },
        }
    }

    /// Opens a session with nonce `nonce` (nonzero; a new host picks one its device's last
    /// session is unlikely to have had): `Open` frames go out until the peer echoes it, and
    /// data frames only after that.
    pub fn open(&mut self, nonce: u16) {
        self.session = nonce.max(1);
        self.opener = true;
        self.opening = true;
    }

    /// The current session's nonce (0: none opened): a device sees a new host as a new
    /// session.
    pub fn session(&self) -> u16 {
        self.session
    }

    /// True once the session is open (or none was asked for).
    pub fn is_open(&self) -> bool {
        !self.opening
    }

    /// Starts over for a new session: sequence numbers from 0, nothing queued either way.
    fn restart_session(&mut self, nonce: u16) {
        self.session = nonce;
        self.tx_head = 0;
        self.tx_len = 0;
        self.tx_sent = 0;
        self.tx_ever = 0;
        self.tx_base = 0;
        self.peer_credits = 1;
        self.probe_every_ms = 0;
        self.rx_head = 0;
        self.rx_len = 0;
        self.rx_next = 0;
        self.ack_due = false;
    }

    /// The timers.
    pub fn config(&self) -> &LinkConfig {
        &self.cfg
    }

    /// The counters.
    pub fn stats(&self) -> &LinkStats {
        &self.stats
    }

    /// Free transmit slots.
    pub fn tx_free(&self) -> usize {
        TX - self.tx_len
    }

    /// True when every sent message has been acknowledged.
    pub fn all_acked(&self) -> bool {
        self.tx_len == 0
    }

    /// Messages waiting for the application.
    pub fn rx_len(&self) -> usize {
        self.rx_len
    }

    /// Queues a message for reliable delivery.
    pub fn send(&mut self, payload: &[u8]) -> Result<(), SendError> {
        if payload.len() > MAX_PAYLOAD {
            return Err(SendError::TooLong);
        }
        push(&mut self.tx, self.tx_head, &mut self.tx_len, payload)
    }

    /// The oldest delivered message, if any (stays until [`Endpoint::pop`]).
    pub fn peek(&self) -> Option<&[u8]> {
        (self.rx_len > 0).then(|| self.rx[self.rx_head].bytes())
    }

    /// The `i`-th delivered message not yet released (0 = oldest).
    pub fn get(&self, i: usize) -> Option<&[u8]> {
        (i < self.rx_len).then(|| self.rx[(self.rx_head + i) % RX].bytes())
    }

    /// Queues a message of this end's own (a job read from the card) after what the link
    /// delivered: the application takes it as it takes the peer's. Its slot is not a credit
    /// for the peer meanwhile (a frame the peer sent on the old credit is dropped and sent
    /// again). `Err(Full)` without a free slot.
    pub fn deliver_local(&mut self, payload: &[u8]) -> Result<(), SendError> {
        if payload.len() > MAX_PAYLOAD {
            return Err(SendError::TooLong);
        }
        push(&mut self.rx, self.rx_head, &mut self.rx_len, payload)
    }

    /// Releases the oldest delivered message (its slot becomes a credit for the peer).
    pub fn pop(&mut self) {
        if self.rx_len > 0 {
            self.rx_head = (self.rx_head + 1) % RX;
            self.rx_len -= 1;
            self.ack_due = true;
        }
    }

    /// Feeds received bytes; `now_ms` stamps the peer's liveness.
    pub fn receive(&mut self, bytes: &[u8], now_ms: u32) {
        if !self.started {
            self.start(now_ms);
        }
        for &b in bytes {
            let frame = match self.decoder.push(b) {
                None => continue,
                Some(Err(_)) => {
                    self.stats.bad_frames += 1;
                    continue;
                }
                Some(Ok(f)) => f,
            };
            self.stats.frames_received += 1;
            self.last_rx_ms = now_ms;
            if frame.kind == FrameType::Open {
                let nonce = u16::from_le_bytes([frame.seq, frame.ack]);
                if self.opener {
                    // Our session is open once echoed: the peer starts from 0, as we do.
                    self.opening &= nonce != self.session;
                } else if nonce != 0 {
                    if nonce != self.session {
                        self.restart_session(nonce);
                    }
                    self.echo_due = true;
                }
                continue;
            }
            if self.opening {
                continue;
            }
            // Acknowledgement: frames before `ack` arrived; only sent frames can be acked.
            let acked = frame.ack.wrapping_sub(self.tx_base) as usize;
            if acked <= self.tx_ever {
                if acked > 0 {
                    self.tx_head = (self.tx_head + acked) % TX;
                    self.tx_len -= acked;
                    self.tx_ever -= acked;
                    self.tx_sent = self.tx_sent.saturating_sub(acked);
                    self.tx_base = frame.ack;
                    self.tx_timer_ms = now_ms;
                }
                self.peer_credits = frame.credits;
            }
            if frame.kind != FrameType::Data {
                continue;
            }
            self.ack_due = true;
            if frame.seq != self.rx_next {
                if (self.rx_next.wrapping_sub(frame.seq) as i8) > 0 {
                    self.stats.duplicates += 1;
                } else {
                    self.stats.out_of_order += 1;
                }
                continue;
            }
            if self.rx_len == RX {
                self.stats.no_room += 1;
                continue;
            }
            let slot = &mut self.rx[(self.rx_head + self.rx_len) % RX];
            slot.buf[..frame.payload.len()].copy_from_slice(frame.payload);
            slot.len = frame.payload.len() as u16;
            self.rx_len += 1;
            self.rx_next = self.rx_next.wrapping_add(1);
            self.stats.delivered += 1;
        }
    }

    fn start(&mut self, now_ms: u32) {
        self.started = true;
        self.last_rx_ms = now_ms;
        self.last_tx_ms = now_ms;
        self.tx_timer_ms = now_ms;
    }

    /// Checks the peer's liveness.
    pub fn check(&mut self, now_ms: u32) -> Result<(), LinkError> {
        if !self.started {
            self.start(now_ms);
        }
        let silent_ms = now_ms.wrapping_sub(self.last_rx_ms);
        if silent_ms >= self.cfg.dead_ms && silent_ms < 1 << 31 {
            return Err(LinkError::Dead { silent_ms });
        }
        Ok(())
    }

    /// The next frame to write, encoded into `out`: a (re)sent data frame the peer has room
    /// for, else a due ack or keepalive. Returns the wire length, or 0 when nothing is due.
    /// Call until it returns 0.
    pub fn poll_transmit(&mut self, now_ms: u32, out: &mut [u8; MAX_WIRE]) -> usize {
        if !self.started {
            self.start(now_ms);
        }
        let credits = (RX - self.rx_len) as u8;
        if self.opening || self.echo_due {
            let due = self.echo_due
                || self.stats.frames_sent == 0
                || now_ms.wrapping_sub(self.last_tx_ms) >= self.cfg.retransmit_ms;
            if !due {
                return 0;
            }
            self.echo_due = false;
            let [lo, hi] = self.session.to_le_bytes();
            let Some(n) = frame::encode(FrameType::Open, lo, hi, credits, &[], out) else {
                return 0;
            };
            self.last_tx_ms = now_ms;
            self.stats.frames_sent += 1;
            self.stats.bytes_sent += n as u64;
            return n;
        }
        let expired =
            self.tx_sent > 0 && now_ms.wrapping_sub(self.tx_timer_ms) >= self.cfg.retransmit_ms;
        // The peer spoke at or after the timer expired, without acking the window.
        let heard_since =
            self.last_rx_ms.wrapping_sub(self.tx_timer_ms) as i32 >= self.cfg.retransmit_ms as i32;
        let mut probe = false;
        if expired && heard_since {
            // Go back N: resend the window from its oldest frame.
            self.stats.retransmits += self.tx_sent as u64;
            self.tx_sent = 0;
            self.tx_timer_ms = now_ms;
            self.probe_every_ms = 0;
        } else if expired {
            let since_probe = now_ms.wrapping_sub(self.probe_ms);
            if self.probe_every_ms == 0 || since_probe >= self.probe_every_ms {
                probe = true;
                self.probe_ms = now_ms;
                let (first, most) = (self.cfg.retransmit_ms.max(1), self.cfg.keepalive_ms);
                self.probe_every_ms = (self.probe_every_ms * 2).clamp(first, most.max(first));
            }
        }
        let n = if probe {
            self.stats.probes += 1;
            let seq = self.tx_base.wrapping_sub(1);
            frame::encode(FrameType::Data, seq, self.rx_next, credits, &[], out)
        } else if self.tx_sent < self.tx_len && self.tx_sent < self.peer_credits as usize {
            let slot = &self.tx[(self.tx_head + self.tx_sent) % TX];
            let seq = self.tx_base.wrapping_add(self.tx_sent as u8);
            if self.tx_sent == 0 {
                self.tx_timer_ms = now_ms;
            }
            self.tx_sent += 1;
            self.tx_ever = self.tx_ever.max(self.tx_sent);
            frame::encode(FrameType::Data, seq, self.rx_next, credits, slot.bytes(), out)
        } else if self.ack_due || now_ms.wrapping_sub(self.last_tx_ms) >= self.cfg.keepalive_ms {
            frame::encode(FrameType::Ack, 0, self.rx_next, credits, &[], out)
        } else {
            None
        };
        let Some(n) = n else { return 0 };
        self.ack_due = false;
        self.last_tx_ms = now_ms;
        self.stats.frames_sent += 1;
        self.stats.bytes_sent += n as u64;
        n
    }
}
