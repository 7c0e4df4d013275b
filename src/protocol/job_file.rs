//! Job files: a sliced-model job kept as the messages its host would stream.
//!
//! The job start, the triangle batches in zmin order and the end of the model, so that a job
//! written to the card prints exactly as it prints streamed: the printer takes each message
//! from the card as it takes it from the link.
//!
//! A file is [`MAGIC`] (which holds the protocol [`VERSION`]), then records
//! `[payload length u16 LE][payload][CRC-32 of the payload, LE]` (the frames' CRC,
//! CRC-32/ISO-HDLC): a record damaged on the card is caught before it is taken.

use crc::{Crc, CRC_32_ISO_HDLC};

use super::frame::{MAX_PAYLOAD, VERSION};

/// The first bytes of a job file: a byte no text starts with, `SJOB`, a line end and the
/// protocol version the messages are in.
pub const MAGIC: [u8; 8] = [0x89, b'S', b'J', b'O', b'B', b'\r', b'\n', VERSION];
/// Bytes of a record's length field.
pub const LEN_BYTES: usize = 2;
/// Bytes of a record's CRC.
pub const CRC_BYTES: usize = 4;
/// Bytes of a record around its payload.
pub const RECORD_OVERHEAD: usize = LEN_BYTES + CRC_BYTES;

const CRC32: Crc<u32> = Crc::<u32>::new(&CRC_32_ISO_HDLC);

/// What is wrong with a job file.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum JobFileError {
    /// It starts with the magic of another protocol version (the byte after `SJOB\r\n`).
    Version(u8),
    /// It is not a job file.
    NotJob,
    /// A record's length is zero or beyond [`MAX_PAYLOAD`].
    Length(u16),
    /// A record's payload does not match its CRC.
    Crc,
    /// The file ends inside a record (or where a record should start).
    Truncated,
}

/// Why a record could not be read: the file's bytes, or the reader under them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ReadError<E> {
    /// The bytes are not a record.
    File(JobFileError),
    /// The reader failed.
    Device(E),
}

impl core::fmt::Display for JobFileError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Version(v) => write!(f, "job file of protocol version {v}, not {VERSION}"),
            Self::NotJob => f.write_str("not a job file"),
            Self::Length(n) => write!(f, "job record of {n} bytes (1..={MAX_PAYLOAD})"),
            Self::Crc => f.write_str("job record does not match its CRC"),
            Self::Truncated => f.write_str("job file ends inside a record"),
        }
    }
}

/// Whether `head` (a file's first bytes) starts a job file of this protocol version.
pub fn check_magic(head: &[u8]) -> Result<(), JobFileError> {
    let Some(magic) = head.get(..MAGIC.len()) else { return Err(JobFileError::NotJob) };
    let (kind, version) = magic.split_at(MAGIC.len() - 1);
    if kind != &MAGIC[..MAGIC.len() - 1] {
        return Err(JobFileError::NotJob);
    }
    if version[0] != VERSION {
        return Err(JobFileError::Version(version[0]));
    }
    Ok(())
}

/// Whether `head` starts with a job file's magic, of any protocol version.
pub fn is_job_file(head: &[u8]) -> bool {
    !matches!(check_magic(head), Err(JobFileError::NotJob))
}

/// The payload length a record's length field gives.
pub fn record_len(field: [u8; LEN_BYTES]) -> Result<usize, JobFileError> {
    let n = u16::from_le_bytes(field);
    if n == 0 || usize::from(n) > MAX_PAYLOAD {
        return Err(JobFileError::Length(n));
    }
    Ok(usize::from(n))
}

/// Checks a record's payload against the CRC stored after it.
pub fn check_record(payload: &[u8], crc: [u8; CRC_BYTES]) -> Result<(), JobFileError> {
    if CRC32.checksum(payload) != u32::from_le_bytes(crc) {
        return Err(JobFileError::Crc);
    }
    Ok(())
}

/// Reads the next record's payload into `payload`, its length and CRC checked: its bytes.
///
/// `read` fills its buffer from the file and says how many bytes it filled (fewer at the
/// file's end).
pub fn read_record<E>(
    mut read: impl FnMut(&mut [u8]) -> Result<usize, E>,
    payload: &mut [u8; MAX_PAYLOAD],
) -> Result<usize, ReadError<E>> {
    let mut exact = |out: &mut [u8]| match read(out) {
        Ok(n) if n == out.len() => Ok(()),
        Ok(_) => Err(ReadError::File(JobFileError::Truncated)),
        Err(e) => Err(ReadError::Device(e)),
    };
    let mut len = [0u8; LEN_BYTES];
    exact(&mut len)?;
    let n = record_len(len).map_err(ReadError::File)?;
    exact(&mut payload[..n])?;
    let mut crc = [0u8; CRC_BYTES];
    exact(&mut crc)?;
    check_record(&payload[..n], crc).map_err(ReadError::File)?;
    Ok(n)
}

/// Writes the record of `payload` (1..=[`MAX_PAYLOAD`] bytes) into `out`: its bytes, or `None`
/// when the payload is out of range or `out` is too small.
pub fn encode_record(payload: &[u8], out: &mut [u8]) -> Option<usize> {
    let n = u16::try_from(payload.len()).ok()?;
    record_len(n.to_le_bytes()).ok()?;
    let total = payload.len() + RECORD_OVERHEAD;
    let out = out.get_mut(..total)?;
    out[..LEN_BYTES].copy_from_slice(&n.to_le_bytes());
    out[LEN_BYTES..LEN_BYTES + payload.len()].copy_from_slice(payload);
    let crc = CRC32.checksum(payload).to_le_bytes();
    out[LEN_BYTES + payload.len()..].copy_from_slice(&crc);
    Some(total)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_record_reads_back_and_any_flipped_bit_is_caught() {
        let payload = [0x11, 3, 0, 42, 7, 9];
        let mut rec = [0u8; 6 + RECORD_OVERHEAD];
        assert_eq!(encode_record(&payload, &mut rec), Some(rec.len()));
        assert_eq!(record_len([rec[0], rec[1]]), Ok(payload.len()));
        let crc = [rec[8], rec[9], rec[10], rec[11]];
        assert_eq!(check_record(&rec[2..8], crc), Ok(()));
        for bit in 0..payload.len() * 8 {
            let mut bad = payload;
            bad[bit / 8] ^= 1 << (bit % 8);
            assert_eq!(check_record(&bad, crc), Err(JobFileError::Crc));
        }
    }

    #[test]
    fn records_read_back_in_turn_and_a_short_file_is_truncated() {
        let mut file = MAGIC.to_vec();
        for payload in [&[0x12][..], &[0x11, 0, 5, 6, 7]] {
            let mut rec = [0u8; 16];
            let n = encode_record(payload, &mut rec).unwrap();
            file.extend_from_slice(&rec[..n]);
        }
        let mut at = MAGIC.len();
        let mut read = |out: &mut [u8]| -> Result<usize, ()> {
            let n = out.len().min(file.len() - at);
            out[..n].copy_from_slice(&file[at..at + n]);
            at += n;
            Ok(n)
        };
        let mut payload = [0u8; MAX_PAYLOAD];
        assert_eq!(read_record(&mut read, &mut payload), Ok(1));
        assert_eq!(payload[0], 0x12);
        assert_eq!(read_record(&mut read, &mut payload), Ok(5));
        assert_eq!(payload[..5], [0x11, 0, 5, 6, 7]);
        let end = read_record(&mut read, &mut payload);
        assert_eq!(end, Err(ReadError::File(JobFileError::Truncated)));
    }

    #[test]
    fn lengths_and_magic_outside_the_format_are_refused() {
        assert_eq!(record_len([0, 0]), Err(JobFileError::Length(0)));
        let over = (MAX_PAYLOAD as u16 + 1).to_le_bytes();
        assert_eq!(record_len(over), Err(JobFileError::Length(MAX_PAYLOAD as u16 + 1)));
        assert_eq!(encode_record(&[], &mut [0u8; 8]), None);
        assert_eq!(encode_record(&[1, 2], &mut [0u8; 7]), None);
        assert_eq!(check_magic(&MAGIC), Ok(()));
        let mut old = MAGIC;
        old[7] = VERSION - 1;
        assert_eq!(check_magic(&old), Err(JobFileError::Version(VERSION - 1)));
        assert!(is_job_file(&old));
        assert_eq!(check_magic(b"G28\nG1 X"), Err(JobFileError::NotJob));
        assert_eq!(check_magic(&MAGIC[..7]), Err(JobFileError::NotJob));
    }
}
