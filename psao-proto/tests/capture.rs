//! Capture files against spec/capture.md: round trips, every error class,
//! bounded reads (a recorded session replaying into a mirror is
//! `tests/tests/capture_replay.rs`).

use proptest::prelude::*;
use psao_proto::capture::*;

fn frame(k: u8, len: usize) -> Vec<u8> {
    vec![k; len]
}

#[test]
fn captures_round_trip() {
    let mut w = CaptureWriter::new(Vec::new()).unwrap();
    w.write(1500, &frame(1, 32)).unwrap();
    w.write(1400, &frame(2, 40)).unwrap(); // raised to 1500
    w.write(9000, &frame(3, 100)).unwrap();
    let bytes = w.finish().unwrap();
    assert_eq!(
        &bytes[..16],
        b"PSAOCAP1\x01\0\0\0\0\0\0\0",
        "the header of spec/capture.md"
    );
    assert_eq!(
        &bytes[16..28],
        &[0xdc, 0x05, 0, 0, 0, 0, 0, 0, 0x20, 0, 0, 0],
        "the example record"
    );
    let records: Vec<_> = CaptureReader::new(&bytes[..], 1 << 20)
        .unwrap()
        .collect::<Result<_, _>>()
        .unwrap();
    assert_eq!(records.len(), 3);
    assert_eq!(
        records.iter().map(|r| r.time_us).collect::<Vec<_>>(),
        [1500, 1500, 9000]
    );
    assert_eq!(&records[2].frame[..], &frame(3, 100)[..]);
    assert_eq!(records[1].offset, 16 + 12 + 32);
    // A header alone is a valid, empty capture.
    let empty = CaptureWriter::new(Vec::new()).unwrap().finish().unwrap();
    assert_eq!(CaptureReader::new(&empty[..], 1 << 20).unwrap().count(), 0);
}

#[test]
fn every_error_class_is_reported() {
    let good = {
        let mut w = CaptureWriter::new(Vec::new()).unwrap();
        w.write(10, &frame(1, 32)).unwrap();
        w.write(20, &frame(2, 64)).unwrap();
        w.finish().unwrap()
    };
    fn open(b: &[u8]) -> Result<CaptureReader<&[u8]>, CaptureError> {
        CaptureReader::new(b, 1 << 20)
    }
    assert!(matches!(open(b"PSAOCAP"), Err(CaptureError::Magic)));
    assert!(matches!(
        open(b"NOTACAPTUREFILE!"),
        Err(CaptureError::Magic)
    ));
    let mut v = good.clone();
    v[8] = 2;
    assert!(matches!(open(&v), Err(CaptureError::Version(2))));
    let mut v = good.clone();
    v[13] = 1;
    assert!(matches!(open(&v), Err(CaptureError::Reserved)));
    let last = |b: &[u8], max: u32| {
        CaptureReader::new(b, max)
            .unwrap()
            .find_map(|r| r.err())
            .expect("an error")
    };
    // A length above the reader's limit: refused before any allocation.
    let mut v = good.clone();
    v[24..28].copy_from_slice(&u32::MAX.to_le_bytes());
    assert!(matches!(
        last(&v, 1 << 20),
        CaptureError::FrameLength {
            offset: 16,
            len: u32::MAX,
            ..
        }
    ));
    let mut v = good.clone();
    v[24..28].copy_from_slice(&31u32.to_le_bytes());
    assert!(matches!(
        last(&v, 1 << 20),
        CaptureError::FrameLength { len: 31, .. }
    ));
    assert!(matches!(
        last(&good, 40),
        CaptureError::FrameLength {
            offset: 60,
            len: 64,
            max: 40
        }
    ));
    // Time going backwards.
    let mut v = good.clone();
    v[60..68].copy_from_slice(&5u64.to_le_bytes());
    assert!(matches!(
        last(&v, 1 << 20),
        CaptureError::Time { offset: 60 }
    ));
    // Cut inside a record header, or inside a frame.
    assert!(matches!(
        last(&good[..good.len() - 70], 1 << 20),
        CaptureError::Truncated { offset: 60 }
    ));
    assert!(matches!(
        last(&good[..good.len() - 1], 1 << 20),
        CaptureError::Truncated { offset: 60 }
    ));
    // Records before an error are still delivered.
    let mut r = CaptureReader::new(&good[..good.len() - 1], 1 << 20).unwrap();
    assert!(r.next().unwrap().is_ok());
    assert!(r.next().unwrap().is_err());
    assert!(r.next().is_none(), "nothing after an error");
}

proptest! {
    #[test]
    fn any_bytes_never_panic_the_reader(bytes in prop::collection::vec(any::<u8>(), 0..600)) {
        let mut v = b"PSAOCAP1\x01\0\0\0\0\0\0\0".to_vec();
        v.extend_from_slice(&bytes);
        if let Ok(r) = CaptureReader::new(&v[..], 256) {
            for rec in r.flatten() {
                prop_assert!(rec.frame.len() <= 256);
            }
        }
    }
}
