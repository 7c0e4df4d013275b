//! Fuzz target for job files (`strata::protocol::job_file`), read as the printer reads one from
//! its card: the magic, then records until the file ends, each payload decoded as a message.
//! With the first input byte odd, every record's CRC is made right before it is read (so the
//! payloads the fuzzer writes reach the decoder); otherwise the bytes are taken as they are.
//!
//! Checks: no panic; a record read is its length field's bytes, within 1..=MAX_PAYLOAD, and
//! matches its CRC; the reader never reads past the file; a triangle batch yields exactly its
//! count of triangles.
#![no_main]

use libfuzzer_sys::fuzz_target;
use strata::protocol::job_file::{self, ReadError, LEN_BYTES, MAGIC, RECORD_OVERHEAD};
use strata::protocol::{Message, MAX_PAYLOAD};

fuzz_target!(|data: &[u8]| {
    let Some((&mode, rest)) = data.split_first() else { return };
    let mut file = MAGIC.to_vec();
    file.extend_from_slice(rest);
    if mode & 1 == 1 {
        fix_crcs(&mut file);
    }
    assert!(job_file::check_magic(&file).is_ok());
    let mut at = MAGIC.len();
    let mut payload = [0u8; MAX_PAYLOAD];
    loop {
        let start = at;
        let mut read = |out: &mut [u8]| -> Result<usize, ()> {
            let n = out.len().min(file.len() - at);
            out[..n].copy_from_slice(&file[at..at + n]);
            at += n;
            Ok(n)
        };
        match job_file::read_record(&mut read, &mut payload) {
            Ok(n) => {
                assert!((1..=MAX_PAYLOAD).contains(&n));
                assert_eq!(at - start, n + RECORD_OVERHEAD, "a record is its length's bytes");
                let len = u16::from_le_bytes([file[start], file[start + 1]]) as usize;
                assert_eq!(len, n);
                if let Ok(Message::Triangles(batch)) = Message::decode(&payload[..n]) {
                    assert_eq!(batch.iter().count(), batch.len());
                }
            }
            Err(ReadError::File(_)) => break,
            Err(ReadError::Device(())) => unreachable!("the slice reader does not fail"),
        }
        assert!(at <= file.len());
    }
});

/// Writes each record's right CRC after it, as far as the lengths lead.
fn fix_crcs(file: &mut [u8]) {
    let mut at = MAGIC.len();
    while at + LEN_BYTES <= file.len() {
        let n = u16::from_le_bytes([file[at], file[at + 1]]) as usize;
        if n == 0 || n > MAX_PAYLOAD || at + n + RECORD_OVERHEAD > file.len() {
            return;
        }
        let body = &file[at + LEN_BYTES..at + LEN_BYTES + n];
        let mut rec = [0u8; MAX_PAYLOAD + RECORD_OVERHEAD];
        let len = job_file::encode_record(body, &mut rec).expect("a valid length");
        file[at..at + len].copy_from_slice(&rec[..len]);
        at += len;
    }
}
