//! A model job as a file for the printer's card (`strata upload MODEL`): the messages
//! `strata print` would stream, in [`strata::protocol::job_file`]'s records.

use strata::geom::Triangle;
use strata::protocol::job_file::{encode_record, MAGIC, RECORD_OVERHEAD};
use strata::protocol::{BatchBuilder, JobSpec, Message, MAX_PAYLOAD};

/// The job file of `job` with `tris` (placed, sorted by lowest z, admitted for the printer):
/// the job start, the triangles in batches as large as a frame takes (as streamed), the end
/// of the model.
pub fn encode(job: &JobSpec, tris: &[Triangle]) -> Result<Vec<u8>, String> {
    let mut out = MAGIC.to_vec();
    let mut record = |payload: &[u8]| {
        let mut rec = [0u8; MAX_PAYLOAD + RECORD_OVERHEAD];
        let n = encode_record(payload, &mut rec).expect("a message fits a record");
        out.extend_from_slice(&rec[..n]);
    };
    let mut buf = [0u8; MAX_PAYLOAD];
    let n = Message::JobStart(*job).encode(&mut buf).map_err(|e| format!("job start: {e:?}"))?;
    record(&buf[..n]);
    let mut batch = BatchBuilder::new();
    let mut next = 0;
    while next < tris.len() {
        next += crate::session::fill_batch(&mut batch, tris, next)?;
        record(batch.payload());
        batch.clear();
    }
    let n = Message::EndOfModel.encode(&mut buf).map_err(|e| format!("end: {e:?}"))?;
    record(&buf[..n]);
    Ok(out)
}
