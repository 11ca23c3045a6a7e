//! Capture files (spec/capture.md): the frames a client received, with
//! their arrival times, for replay and inspection.

use std::io::{Read, Write};

use bytes::Bytes;

/// The file magic.
pub const CAPTURE_MAGIC: [u8; 8] = *b"PSAOCAP1";

/// Header length.
pub const CAPTURE_HEADER_LEN: usize = 16;

/// What was wrong with a capture file.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum CaptureError {
    /// Shorter than the header, or not starting with `PSAOCAP1`.
    #[error("magic: not a PSAO capture file")]
    Magic,
    /// An unknown version.
    #[error("version: {0} (this reader knows 1)")]
    Version(u16),
    /// A reserved field is not 0.
    #[error("reserved: a reserved header field is not 0")]
    Reserved,
    /// A record's frame length is out of range.
    #[error("frame_length: record at byte {offset} holds {len} bytes (allowed 32..={max})")]
    FrameLength {
        /// Where the record starts.
        offset: u64,
        /// Its length field.
        len: u32,
        /// The reader's limit.
        max: u32,
    },
    /// Arrival times go backwards.
    #[error("time: record at byte {offset} arrives before the one before it")]
    Time {
        /// Where the record starts.
        offset: u64,
    },
    /// The file ends inside a record.
    #[error("truncated: the record at byte {offset} is cut short")]
    Truncated {
        /// Where the record starts.
        offset: u64,
    },
    /// Reading or writing failed.
    #[error("i/o: {0}")]
    Io(#[from] std::io::Error),
}

/// Writes a capture.
#[derive(Debug)]
pub struct CaptureWriter<W: Write> {
    out: W,
    last: u64,
}

impl<W: Write> CaptureWriter<W> {
    /// Writes the header.
    pub fn new(mut out: W) -> Result<CaptureWriter<W>, CaptureError> {
        let mut h = [0u8; CAPTURE_HEADER_LEN];
        h[..8].copy_from_slice(&CAPTURE_MAGIC);
        h[8..10].copy_from_slice(&1u16.to_le_bytes());
        out.write_all(&h)?;
        Ok(CaptureWriter { out, last: 0 })
    }

    /// Appends a frame that arrived `time_us` after the start (times
    /// before the previous one are raised to it).
    pub fn write(&mut self, time_us: u64, frame: &[u8]) -> Result<(), CaptureError> {
        let t = time_us.max(self.last);
        self.last = t;
        self.out.write_all(&t.to_le_bytes())?;
        self.out.write_all(&(frame.len() as u32).to_le_bytes())?;
        self.out.write_all(frame)?;
        Ok(())
    }

    /// Flushes and returns the writer.
    pub fn finish(mut self) -> Result<W, CaptureError> {
        self.out.flush()?;
        Ok(self.out)
    }
}

/// One record of a capture.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct CaptureRecord {
    /// Microseconds from the start.
    pub time_us: u64,
    /// The frame.
    pub frame: Bytes,
    /// Where the record starts in the file.
    pub offset: u64,
}

/// Reads a capture record by record.
#[derive(Debug)]
pub struct CaptureReader<R: Read> {
    input: R,
    max_frame_bytes: u32,
    offset: u64,
    last: u64,
    failed: bool,
}

/// Reads until `buf` is full; returns how many bytes were read (less at
/// the end of the input).
fn fill<R: Read>(r: &mut R, buf: &mut [u8]) -> std::io::Result<usize> {
    let mut n = 0;
    while n < buf.len() {
        match r.read(&mut buf[n..]) {
            Ok(0) => break,
            Ok(k) => n += k,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
    Ok(n)
}

impl<R: Read> CaptureReader<R> {
    /// Checks the header; records longer than `max_frame_bytes` are
    /// refused.
    pub fn new(mut input: R, max_frame_bytes: u32) -> Result<CaptureReader<R>, CaptureError> {
        let mut h = [0u8; CAPTURE_HEADER_LEN];
        if fill(&mut input, &mut h)? < CAPTURE_HEADER_LEN || h[..8] != CAPTURE_MAGIC {
            return Err(CaptureError::Magic);
        }
        let version = u16::from_le_bytes([h[8], h[9]]);
        if version != 1 {
            return Err(CaptureError::Version(version));
        }
        if h[10..].iter().any(|&b| b != 0) {
            return Err(CaptureError::Reserved);
        }
        Ok(CaptureReader {
            input,
            max_frame_bytes,
            offset: CAPTURE_HEADER_LEN as u64,
            last: 0,
            failed: false,
        })
    }

    /// The next record; `None` at the end of the file. After an error it
    /// returns `None`.
    pub fn next_record(&mut self) -> Option<Result<CaptureRecord, CaptureError>> {
        if self.failed {
            return None;
        }
        let r = self.read_record().transpose();
        if matches!(r, Some(Err(_))) {
            self.failed = true;
        }
        r
    }

    fn read_record(&mut self) -> Result<Option<CaptureRecord>, CaptureError> {
        let offset = self.offset;
        let mut h = [0u8; 12];
        let n = fill(&mut self.input, &mut h)?;
        if n == 0 {
            return Ok(None);
        }
        if n < 12 {
            return Err(CaptureError::Truncated { offset });
        }
        let time_us = u64::from_le_bytes(h[..8].try_into().expect("8 bytes"));
        let len = u32::from_le_bytes(h[8..].try_into().expect("4 bytes"));
        if !(32..=self.max_frame_bytes).contains(&len) {
            return Err(CaptureError::FrameLength {
                offset,
                len,
                max: self.max_frame_bytes,
            });
        }
        if time_us < self.last {
            return Err(CaptureError::Time { offset });
        }
        let mut frame = vec![0u8; len as usize];
        if fill(&mut self.input, &mut frame)? < len as usize {
            return Err(CaptureError::Truncated { offset });
        }
        self.last = time_us;
        self.offset += 12 + len as u64;
        Ok(Some(CaptureRecord {
            time_us,
            frame: frame.into(),
            offset,
        }))
    }
}

impl<R: Read> Iterator for CaptureReader<R> {
    type Item = Result<CaptureRecord, CaptureError>;

    fn next(&mut self) -> Option<Self::Item> {
        self.next_record()
    }
}
