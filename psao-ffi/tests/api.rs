//! The C API against the Rust API it wraps: the same outcomes and typed
//! errors for every vector, the same frames from the same server calls,
//! the same reconstruction; and the boundary's own rules (NULL pointers,
//! short buffers, invalid arguments, outputs written only on success).
//!
//! Soundness of the `unsafe` blocks: each calls a C entry point as a C
//! caller would, with pointers to live local values and buffers of the
//! types and lengths its `# Safety` section asks for (or NULL where the
//! test checks that NULL is refused), on objects made by the `_new`
//! functions, freed once, on one thread; `assume_init` follows only a call
//! that returned `PSAO_OK`, which writes its output.
#![allow(unsafe_code)]

use std::path::PathBuf;
use std::ptr::{null, null_mut};

use glam::{UVec3, Vec3};
use psao_codec::{
    Change, Decoder, Encoder, EncoderConfig, Event, GridTable, InstanceDef, Limits, Thresholds,
    reconstruct_ao,
};
use psao_ffi::*;

type R = psao_result;

fn unhex(s: &str) -> Vec<u8> {
    (0..s.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&s[i..i + 2], 16).unwrap())
        .collect()
}

fn decoder(limits: Option<&psao_limits>) -> *mut psao_decoder {
    let mut d = null_mut();
    let r = unsafe { psao_decoder_new(limits.map_or(null(), |l| l as *const _), &mut d) };
    assert_eq!(r, R::PSAO_OK);
    d
}

fn name(r: R) -> String {
    unsafe { std::ffi::CStr::from_ptr(psao_result_name(r as u32)) }
        .to_str()
        .unwrap()
        .to_string()
}

fn decoder_error(d: *mut psao_decoder) -> String {
    let mut buf = vec![0u8; 1024];
    let mut len = 0;
    let r = unsafe { psao_decoder_last_error(d, buf.as_mut_ptr().cast(), buf.len(), &mut len) };
    assert_eq!(r, R::PSAO_OK);
    assert_eq!(buf[len], 0, "NUL-terminated");
    String::from_utf8(buf[..len].to_vec()).unwrap()
}

fn receive(d: *mut psao_decoder, frame: &[u8]) -> Result<psao_event, R> {
    let mut ev = std::mem::MaybeUninit::<psao_event>::uninit();
    let r = unsafe { psao_decoder_receive(d, frame.as_ptr(), frame.len(), ev.as_mut_ptr()) };
    if r == R::PSAO_OK {
        Ok(unsafe { ev.assume_init() })
    } else {
        Err(r)
    }
}

fn c_changes(d: *mut psao_decoder) -> (bool, Vec<psao_change>) {
    let (mut len, mut all) = (0usize, 0u8);
    let r = unsafe { psao_decoder_changes(d, null_mut(), 0, &mut len, &mut all) };
    assert!(r == R::PSAO_OK || r == R::PSAO_ERROR_BUFFER_TOO_SHORT);
    let mut out = vec![
        psao_change {
            kind: psao_change_kind::PSAO_CHANGE_DEFINED,
            instance: 0,
            start: 0,
            end: 0
        };
        len
    ];
    let r = unsafe { psao_decoder_changes(d, out.as_mut_ptr(), out.len(), &mut len, &mut all) };
    assert_eq!(r, R::PSAO_OK);
    (all == 1, out)
}

fn rust_change(c: &Change) -> (psao_change_kind, u32, u32, u32) {
    use psao_change_kind::*;
    match c {
        Change::Defined(i) => (PSAO_CHANGE_DEFINED, *i, 0, 0),
        Change::Removed(i) => (PSAO_CHANGE_REMOVED, *i, 0, 0),
        Change::Transform(i) => (PSAO_CHANGE_TRANSFORM, *i, 0, 0),
        Change::Buckets(i, r) => (PSAO_CHANGE_BUCKETS, *i, r.start, r.end),
        Change::Words(i, r) => (PSAO_CHANGE_WORDS, *i, r.start, r.end),
        other => panic!("a change kind the test does not know: {other:?}"),
    }
}

/// Instance `id`'s words and bucket entries through the C API.
fn c_arrays(d: *mut psao_decoder, id: u32) -> (Vec<u32>, Vec<(u32, u32)>) {
    let mut info = std::mem::MaybeUninit::<psao_instance_info>::uninit();
    assert_eq!(
        unsafe { psao_decoder_instance(d, id, info.as_mut_ptr()) },
        R::PSAO_OK
    );
    let info = unsafe { info.assume_init() };
    let mut words = vec![0u32; info.words as usize];
    let r = unsafe { psao_decoder_copy_words(d, id, 0, words.len(), words.as_mut_ptr()) };
    assert_eq!(r, R::PSAO_OK);
    let mut entries = vec![psao_bucket_entry { key: 0, cell: 0 }; info.bucket_entries as usize];
    let r = unsafe { psao_decoder_copy_buckets(d, id, 0, entries.len(), entries.as_mut_ptr()) };
    assert_eq!(r, R::PSAO_OK);
    (words, entries.iter().map(|e| (e.key, e.cell)).collect())
}

#[test]
fn every_vector_gives_the_rust_outcome_error_and_state_through_the_c_api() {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../spec/vectors");
    let mut paths: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|x| x == "txt"))
        .collect();
    paths.sort();
    assert!(paths.len() >= 62);
    let mut errors = 0;
    for path in &paths {
        let text = std::fs::read_to_string(path).unwrap();
        let mut limits = Limits::default();
        let mut pair: Option<(Decoder, *mut psao_decoder)> = None;
        for line in text.lines() {
            let (word, rest) = line.split_once(' ').unwrap_or((line, ""));
            match word {
                "limit" => {
                    let (n, v) = rest.split_once(' ').unwrap();
                    assert!(limits.set(n, v.parse().unwrap()));
                }
                "frame" => {
                    let (rust, c) = pair.get_or_insert_with(|| {
                        (Decoder::new(limits), decoder(Some(&limits.into())))
                    });
                    let frame = unhex(rest);
                    let want = rust.receive(&frame);
                    let got = receive(*c, &frame);
                    match (&want, got) {
                        (Err(e), Err(code)) => {
                            assert_eq!(name(code), e.code(), "{path:?}");
                            assert_eq!(decoder_error(*c), e.to_string(), "{path:?}");
                            errors += 1;
                        }
                        (Ok(event), Ok(ev)) => assert_eq!(ev, expected_event(event), "{path:?}"),
                        (want, got) => panic!("{path:?}: Rust {want:?}, C {got:?}"),
                    }
                    let mut digest = 0;
                    let r = unsafe { psao_decoder_digest(*c, &mut digest) };
                    match rust.mirror().digest() {
                        Some(d) => assert_eq!((r, digest), (R::PSAO_OK, d)),
                        None => assert_eq!(r, R::PSAO_ERROR_NO_STATE),
                    }
                    let (all, items) = c_changes(*c);
                    let changes = rust.mirror().changes();
                    assert_eq!(all, changes.all);
                    let items: Vec<_> = items
                        .iter()
                        .map(|c| (c.kind, c.instance, c.start, c.end))
                        .collect();
                    let want: Vec<_> = changes.items.iter().map(rust_change).collect();
                    assert_eq!(items, want, "{path:?}: changes");
                }
                _ => {}
            }
        }
        let (rust, c) = pair.expect("a frame");
        for (id, m) in rust.mirror().instances() {
            let (words, buckets) = c_arrays(c, id);
            assert_eq!(words, m.words());
            let want: Vec<_> = m.buckets().iter().map(|e| (e.key, e.cell)).collect();
            assert_eq!(buckets, want);
        }
        unsafe { psao_decoder_free(c) };
    }
    assert!(errors >= 40, "{errors} error vectors");
}

fn expected_event(e: &Event) -> psao_event {
    let mut out = psao_event {
        kind: psao_event_kind::PSAO_EVENT_APPLIED,
        sequence: 0,
        keyframe: 0,
        have_valid: 0,
        have: 0,
        base: 0,
    };
    match *e {
        Event::Applied { sequence, keyframe } => {
            out.sequence = sequence;
            out.keyframe = keyframe as u8;
        }
        Event::Stale { sequence, have } => {
            out.kind = psao_event_kind::PSAO_EVENT_STALE;
            (out.sequence, out.have, out.have_valid) = (sequence, have, 1);
        }
        Event::NeedKeyframe {
            have,
            base,
            sequence,
        } => {
            out.kind = psao_event_kind::PSAO_EVENT_NEED_KEYFRAME;
            (out.sequence, out.base) = (sequence, base);
            (out.have, out.have_valid) = (have.unwrap_or(0), have.is_some() as u8);
        }
        _ => panic!("an event the test does not know"),
    }
    out
}

fn def() -> InstanceDef {
    InstanceDef {
        origin: Vec3::splat(-1.0),
        cell_size: Vec3::splat(0.25),
        dims: UVec3::splat(8),
        table_log2: 6,
        bucket_capacity: 8,
        cell_capacity: 7,
        cell_pool: 256,
        point_format: 0,
        overflow: true,
        radius: 0.2,
        t_n: 0.1,
        t_d: 0.7,
    }
}

fn c_def(d: &InstanceDef) -> psao_instance_def {
    psao_instance_def::from(d)
}

/// The keyframe of instance 3 of `d` holding one point (id 0 at
/// (0.1, 0.1, 0.1), normal +y, AO 0.25), with transform `m` if given.
fn one_point_keyframe(d: InstanceDef, m: Option<[f32; 12]>) -> Vec<u8> {
    let mut rt = GridTable::new(3, d, 10).unwrap();
    rt.set_point(0, Vec3::new(0.1, 0.1, 0.1), Vec3::Y, 0.25)
        .unwrap();
    rt.take_dirty();
    let mut enc = Encoder::new(EncoderConfig::default());
    let mut b = enc.keyframe();
    b.snapshot(&rt).unwrap();
    if let Some(m) = m {
        b.transform(3, 1, &m);
    }
    b.finish().unwrap().unwrap().bytes.to_vec()
}

fn point(i: u32, tick: u32) -> (Vec3, Vec3, f32) {
    let a = i as f32 * 0.37;
    let p = Vec3::new(0.8 * a.cos(), -0.9 + 0.01 * i as f32, 0.8 * a.sin());
    let ao = ((i * 7 + tick * 13) % 100) as f32 / 100.0;
    (p, Vec3::new(a.cos(), 0.2, a.sin()), ao)
}

/// Sets points `0..count` of [`point`] at `tick` through the C API.
fn set_points(t: *mut psao_table, count: u32, tick: u32) {
    for i in 0..count {
        let (p, n, ao) = point(i, tick);
        let r = unsafe {
            psao_table_set_point(
                t,
                i,
                p.to_array().as_ptr(),
                n.to_array().as_ptr(),
                ao,
                null_mut(),
            )
        };
        assert_eq!(r, R::PSAO_OK);
    }
}

fn table(d: &InstanceDef, max_points: u32) -> *mut psao_table {
    let mut t = null_mut();
    let r = unsafe { psao_table_new(3, &c_def(d), max_points, null(), &mut t) };
    assert_eq!(r, R::PSAO_OK);
    t
}

fn encoder(cfg: &psao_encoder_config) -> *mut psao_encoder {
    let mut e = null_mut();
    assert_eq!(unsafe { psao_encoder_new(cfg, 0, &mut e) }, R::PSAO_OK);
    e
}

fn finish(e: *mut psao_encoder) -> Vec<u8> {
    let mut buf = vec![0u8; 1 << 20];
    let mut len = 0;
    let r = unsafe { psao_encoder_finish(e, buf.as_mut_ptr(), buf.len(), &mut len, null_mut()) };
    assert_eq!(r, R::PSAO_OK);
    buf.truncate(len);
    buf
}

#[test]
fn the_c_server_half_writes_the_rust_encoders_frames_byte_for_byte() {
    for compression in 0..3u32 {
        let mut cfg = psao_encoder_config_default();
        cfg.compression = compression;
        let rust_cfg = EncoderConfig {
            compression: [
                psao_codec::Compression::None,
                psao_codec::Compression::Lz4,
                psao_codec::Compression::Zstd,
            ][compression as usize],
            ..EncoderConfig::default()
        };
        let (ct, ce) = (table(&def(), 500), encoder(&cfg));
        let mut rt = GridTable::new(3, def(), 500).unwrap();
        let mut re = Encoder::new(rust_cfg);
        let th = Thresholds::default();
        let cth = psao_thresholds_default();
        for tick in 0..6 {
            for i in 0..400 {
                let (p, n, ao) = point(i, tick);
                let mut sent = 9;
                let r = unsafe {
                    psao_table_update_point(
                        ct,
                        i,
                        p.to_array().as_ptr(),
                        n.to_array().as_ptr(),
                        ao,
                        &cth,
                        &mut sent,
                    )
                };
                assert_eq!(r, R::PSAO_OK);
                assert_eq!(sent == 1, rt.update_point(i, p, n, ao, &th).unwrap());
            }
            let xf = psao_transform {
                sequence: tick,
                matrix: [
                    1.0,
                    0.0,
                    0.0,
                    0.0,
                    1.0,
                    0.0,
                    0.0,
                    0.0,
                    1.0,
                    tick as f32,
                    0.0,
                    0.0,
                ],
            };
            unsafe {
                assert_eq!(psao_encoder_begin(ce, 0), R::PSAO_OK);
                if tick == 0 {
                    assert_eq!(
                        psao_encoder_define_instance(ce, 3, &c_def(&def())),
                        R::PSAO_OK
                    );
                }
                assert_eq!(psao_encoder_transform(ce, 3, &xf), R::PSAO_OK);
                assert_eq!(psao_encoder_changes(ce, ct), R::PSAO_OK);
            }
            let got = finish(ce);
            let mut b = re.delta();
            if tick == 0 {
                b.define_instance(3, &def()).unwrap();
            }
            b.transform(3, tick, &xf.matrix);
            b.changes(&mut rt);
            let want = b.finish().unwrap().unwrap();
            assert_eq!(
                got,
                &want.bytes[..],
                "delta {tick}, compression {compression}"
            );
        }
        // A keyframe, both ways.
        unsafe {
            assert_eq!(psao_encoder_begin(ce, 1), R::PSAO_OK);
            assert_eq!(psao_encoder_snapshot(ce, ct), R::PSAO_OK);
        }
        let got = finish(ce);
        let mut b = re.keyframe();
        b.snapshot(&rt).unwrap();
        assert_eq!(got, &b.finish().unwrap().unwrap().bytes[..]);
        unsafe {
            psao_table_free(ct);
            psao_encoder_free(ce);
        }
    }
}

#[test]
fn null_pointers_are_refused_with_a_code_and_outputs_stay_untouched() {
    let null_d: *mut psao_decoder = null_mut();
    let null_t: *mut psao_table = null_mut();
    let null_e: *mut psao_encoder = null_mut();
    let np = R::PSAO_ERROR_NULL_POINTER;
    let (mut u, mut z, mut b, mut f) = (0u32, 0usize, 0u8, 0f32);
    let v = [0f32; 3];
    unsafe {
        assert_eq!(psao_decoder_new(null(), null_mut()), np);
        assert_eq!(psao_decoder_receive(null_d, null(), 0, null_mut()), np);
        assert_eq!(psao_decoder_sequence(null_d, &mut u), np);
        assert_eq!(psao_decoder_digest(null_d, &mut u), np);
        assert_eq!(psao_decoder_instance_ids(null_d, null_mut(), 0, &mut z), np);
        assert_eq!(
            psao_decoder_changes(null_d, null_mut(), 0, &mut z, &mut b),
            np
        );
        assert_eq!(psao_decoder_clear_changes(null_d), np);
        assert_eq!(psao_decoder_copy_words(null_d, 0, 0, 0, null_mut()), np);
        assert_eq!(
            psao_decoder_reconstruct(null_d, 0, v.as_ptr(), v.as_ptr(), &mut f),
            np
        );
        assert_eq!(psao_decoder_last_error(null_d, null_mut(), 0, &mut z), np);
        assert_eq!(psao_table_new(0, null(), 1, null(), null_mut()), np);
        assert_eq!(psao_table_get_stats(null_t, null_mut()), np);
        assert_eq!(psao_encoder_new(null(), 0, null_mut()), np);
        assert_eq!(psao_encoder_begin(null_e, 0), np);
        assert_eq!(
            psao_encoder_finish(null_e, null_mut(), 0, &mut z, null_mut()),
            np
        );
        assert_eq!(psao_point_word_fields(0, null_mut()), np);
        // Freeing NULL is a no-op.
        psao_decoder_free(null_d);
        psao_table_free(null_t);
        psao_encoder_free(null_e);
    }

    // A live object with a NULL argument: the code, a message naming the
    // argument, and no output written.
    let d = decoder(None);
    let t = table(&def(), 10);
    let e = encoder(&psao_encoder_config_default());
    unsafe {
        assert_eq!(
            psao_decoder_receive(d, null(), 5, &mut psao_event_zero()),
            np
        );
        assert!(decoder_error(d).contains("`bytes`"), "{}", decoder_error(d));
        assert_eq!(
            psao_decoder_receive(d, [0u8; 4].as_ptr(), 4, null_mut()),
            np
        );
        // No bytes at all is a frame too short, not a NULL pointer.
        let r = psao_decoder_receive(d, null(), 0, &mut psao_event_zero());
        assert_eq!(name(r), "truncated");
        let mut seq = 77u32;
        assert_eq!(psao_decoder_sequence(d, &mut seq), R::PSAO_ERROR_NO_STATE);
        assert_eq!(seq, 77, "output written only on success");
        assert_eq!(
            psao_decoder_reconstruct(d, 1, null(), v.as_ptr(), &mut f),
            np
        );
        assert_eq!(
            psao_table_set_point(t, 0, null(), v.as_ptr(), 0.5, null_mut()),
            np
        );
        assert_eq!(
            psao_table_update_point(t, 0, v.as_ptr(), v.as_ptr(), 0.5, null(), null_mut()),
            np
        );
        assert_eq!(psao_encoder_begin(e, 0), R::PSAO_OK);
        assert_eq!(psao_encoder_changes(e, null_mut()), np);
        assert_eq!(psao_encoder_define_instance(e, 1, null()), np);
        assert_eq!(psao_encoder_transform(e, 1, null()), np);
        assert_eq!(
            psao_encoder_finish(e, null_mut(), 0, null_mut(), null_mut()),
            np
        );
        psao_decoder_free(d);
        psao_table_free(t);
        psao_encoder_free(e);
    }
}

fn psao_event_zero() -> psao_event {
    psao_event {
        kind: psao_event_kind::PSAO_EVENT_APPLIED,
        sequence: 0,
        keyframe: 0,
        have_valid: 0,
        have: 0,
        base: 0,
    }
}

#[test]
fn short_buffers_get_the_length_needed_and_nothing_written() {
    let (t, e) = (table(&def(), 500), encoder(&psao_encoder_config_default()));
    set_points(t, 300, 0);
    unsafe {
        assert_eq!(psao_encoder_begin(e, 0), R::PSAO_OK);
        assert_eq!(
            psao_encoder_define_instance(e, 3, &c_def(&def())),
            R::PSAO_OK
        );
        assert_eq!(psao_encoder_changes(e, t), R::PSAO_OK);
    }
    // The frame does not fit: its size comes back, the buffer is
    // untouched, and the frame waits for the next call.
    let mut small = vec![0xAAu8; 16];
    let mut len = 0;
    let mut info = psao_frame_info {
        sequence: 0,
        keyframe: 0,
        bytes: 0,
        messages: 0,
        points: 0,
        payload_bytes: 0,
    };
    let r = unsafe { psao_encoder_finish(e, small.as_mut_ptr(), small.len(), &mut len, &mut info) };
    assert_eq!(r, R::PSAO_ERROR_BUFFER_TOO_SHORT);
    assert!(len > 16);
    assert!(small.iter().all(|&b| b == 0xAA));
    assert_eq!(info.bytes, 0, "info written only on success");
    // A new frame cannot begin while the finished one waits.
    assert_eq!(
        unsafe { psao_encoder_begin(e, 0) },
        R::PSAO_ERROR_FRAME_OPEN
    );
    let mut frame = vec![0u8; len];
    let r = unsafe { psao_encoder_finish(e, frame.as_mut_ptr(), frame.len(), &mut len, &mut info) };
    assert_eq!(r, R::PSAO_OK);
    assert_eq!((info.sequence, info.bytes as usize), (1, frame.len()));
    let mut stats = std::mem::MaybeUninit::<psao_table_stats>::uninit();
    assert_eq!(
        unsafe { psao_table_get_stats(t, stats.as_mut_ptr()) },
        R::PSAO_OK
    );
    let stats = unsafe { stats.assume_init() };
    assert_eq!(info.points, stats.stored);
    assert!(stats.stored > 100 && stats.out_of_grid > 0, "{stats:?}");

    let d = decoder(None);
    // The decoder wants a keyframe first.
    let ev = receive(d, &frame).unwrap();
    assert_eq!(ev.kind, psao_event_kind::PSAO_EVENT_NEED_KEYFRAME);
    assert_eq!((ev.have_valid, ev.base, ev.sequence), (0, 0, 1));
    unsafe {
        assert_eq!(psao_encoder_begin(e, 1), R::PSAO_OK);
        assert_eq!(psao_encoder_snapshot(e, t), R::PSAO_OK);
    }
    let kf = finish(e);
    let ev = receive(d, &kf).unwrap();
    assert_eq!(
        (ev.kind, ev.sequence, ev.keyframe),
        (psao_event_kind::PSAO_EVENT_APPLIED, 1, 1)
    );

    // Instance ids and changes: a zero capacity asks for the count.
    let mut n = 0usize;
    let r = unsafe { psao_decoder_instance_ids(d, null_mut(), 0, &mut n) };
    assert_eq!((r, n), (R::PSAO_ERROR_BUFFER_TOO_SHORT, 1));
    let mut ids = [0u32; 1];
    assert_eq!(
        unsafe { psao_decoder_instance_ids(d, ids.as_mut_ptr(), 1, &mut n) },
        R::PSAO_OK
    );
    assert_eq!(ids, [3]);
    let mut all = 0;
    let r = unsafe { psao_decoder_changes(d, null_mut(), 0, &mut n, &mut all) };
    assert_eq!(all, 1, "a keyframe changes everything");
    assert!(r == R::PSAO_OK || (r == R::PSAO_ERROR_BUFFER_TOO_SHORT && n > 0));

    // A range beyond the instance's arrays.
    let mut words = vec![0u32; 4];
    let cells = def().cell_pool * def().cell_capacity as u32;
    let r = unsafe { psao_decoder_copy_words(d, 3, cells - 2, 4, words.as_mut_ptr()) };
    assert_eq!(r, R::PSAO_ERROR_OUT_OF_RANGE);
    assert_eq!(words, [0; 4]);
    let r = unsafe { psao_decoder_copy_words(d, 9, 0, 4, words.as_mut_ptr()) };
    assert_eq!(r, R::PSAO_ERROR_NOT_FOUND);

    // The message buffer: too short gets nothing and the length.
    let mut msg = [0x55u8; 8];
    let r = unsafe { psao_decoder_last_error(d, msg.as_mut_ptr().cast(), msg.len(), &mut n) };
    assert_eq!(r, R::PSAO_ERROR_BUFFER_TOO_SHORT);
    assert_eq!(
        n,
        decoder_error(d).len() + 1,
        "the bytes needed, NUL included"
    );
    assert!(n > 8 && msg.iter().all(|&b| b == 0x55));
    unsafe {
        psao_decoder_free(d);
        psao_table_free(t);
        psao_encoder_free(e);
    }
}

#[test]
fn invalid_arguments_and_misuse_get_typed_errors() {
    let mut bad = c_def(&def());
    bad.overflow = 2;
    let mut t = null_mut();
    unsafe {
        assert_eq!(
            psao_table_new(1, &bad, 10, null(), &mut t),
            R::PSAO_ERROR_INVALID_ARGUMENT
        );
        bad.overflow = 1;
        bad.cell_capacity = 9;
        assert_eq!(
            psao_table_new(1, &bad, 10, null(), &mut t),
            R::PSAO_ERROR_INVALID_DEFINITION
        );
        let mut limits = psao_limits_default();
        limits.max_cell_pool = 100;
        assert_eq!(
            psao_table_new(1, &c_def(&def()), 10, &limits, &mut t),
            R::PSAO_ERROR_RESOURCE_LIMIT
        );
        assert!(t.is_null(), "no object on failure");
    }
    let mut cfg = psao_encoder_config_default();
    let mut e = null_mut();
    for (field, r) in [
        (0, R::PSAO_ERROR_INVALID_ARGUMENT),
        (1, R::PSAO_ERROR_INVALID_ARGUMENT),
        (2, R::PSAO_ERROR_INVALID_ARGUMENT),
    ] {
        let mut c = cfg;
        match field {
            0 => c.compression = 9,
            1 => c.zstd_level = 23,
            _ => c.checksum = 3,
        }
        assert_eq!(unsafe { psao_encoder_new(&c, 0, &mut e) }, r);
    }
    cfg.limits.max_frame_bytes = 64;
    cfg.compression = 0;
    let e = encoder(&cfg);
    let t = table(&def(), 10);
    let v = Vec3::new(0.1, 0.2, 0.3).to_array();
    let mut s = String::new();
    unsafe {
        let mut placement = std::mem::MaybeUninit::<psao_placement>::uninit();
        assert_eq!(
            psao_table_set_point(t, 10, v.as_ptr(), v.as_ptr(), 0.5, placement.as_mut_ptr()),
            R::PSAO_ERROR_POINT_ID
        );
        let out = [5.0f32, 0.0, 0.0];
        assert_eq!(
            psao_table_set_point(t, 1, out.as_ptr(), v.as_ptr(), 0.5, placement.as_mut_ptr()),
            R::PSAO_OK
        );
        let p = placement.assume_init();
        assert_eq!(p.kind, psao_placement_kind::PSAO_PLACEMENT_DROPPED);
        assert_eq!(p.drop_reason, psao_drop_reason::PSAO_DROP_OUT_OF_GRID);
        assert_eq!(
            psao_table_set_point(t, 2, v.as_ptr(), v.as_ptr(), 0.5, null_mut()),
            R::PSAO_OK
        );
        assert_eq!(
            psao_encoder_finish(e, null_mut(), 0, &mut 0, null_mut()),
            R::PSAO_ERROR_NO_FRAME_OPEN
        );
        assert_eq!(psao_encoder_changes(e, t), R::PSAO_ERROR_NO_FRAME_OPEN);
        assert_eq!(psao_encoder_begin(e, 2), R::PSAO_ERROR_INVALID_ARGUMENT);
        assert_eq!(psao_encoder_begin(e, 1), R::PSAO_OK);
        assert_eq!(psao_encoder_begin(e, 0), R::PSAO_ERROR_FRAME_OPEN);
        assert_eq!(psao_encoder_snapshot(e, t), R::PSAO_ERROR_PENDING_CHANGES);
        let nan = psao_transform {
            sequence: 1,
            matrix: [f32::NAN; 12],
        };
        assert_eq!(
            psao_encoder_transform(e, 1, &nan),
            R::PSAO_ERROR_NON_FINITE_TRANSFORM
        );
        assert_eq!(psao_encoder_abort(e), R::PSAO_OK);
        // A delta beyond the receivers' 64-byte frames: refused, and its
        // sequence skipped so that clients see the gap.
        assert_eq!(psao_encoder_begin(e, 0), R::PSAO_OK);
        assert_eq!(
            psao_encoder_define_instance(e, 3, &c_def(&def())),
            R::PSAO_OK
        );
        assert_eq!(psao_encoder_changes(e, t), R::PSAO_OK);
        let mut buf = vec![0u8; 4096];
        let r = psao_encoder_finish(e, buf.as_mut_ptr(), buf.len(), &mut 0, null_mut());
        assert_eq!(r, R::PSAO_ERROR_RECEIVER_LIMIT);
        let mut msg = vec![0u8; 256];
        let mut n = 0;
        assert_eq!(
            psao_encoder_last_error(e, msg.as_mut_ptr().cast(), msg.len(), &mut n),
            R::PSAO_OK
        );
        s.push_str(std::str::from_utf8(&msg[..n]).unwrap());
        let mut seq = 0;
        assert_eq!(psao_encoder_sequence(e, &mut seq), R::PSAO_OK);
        assert_eq!(seq, 1);
        // An empty delta is no frame.
        assert_eq!(psao_encoder_begin(e, 0), R::PSAO_OK);
        let mut len = 99;
        let r = psao_encoder_finish(e, null_mut(), 0, &mut len, null_mut());
        assert_eq!((r, len), (R::PSAO_OK, 0));
        psao_table_free(t);
        psao_encoder_free(e);
    }
    assert!(s.contains("frame bytes") && s.contains("64"), "{s}");
}

#[test]
fn reconstruction_through_the_c_api_is_the_rust_functions() {
    let mut rt = GridTable::new(3, def(), 500).unwrap();
    let mut enc = Encoder::new(EncoderConfig::default());
    for i in 0..400 {
        let (p, n, ao) = point(i, 2);
        rt.set_point(i, p, n, ao).unwrap();
    }
    rt.take_dirty();
    let mut b = enc.keyframe();
    b.snapshot(&rt).unwrap();
    // A transform: rotate a quarter turn about y and move.
    let m = [0.0, 0.0, -1.0, 0.0, 1.0, 0.0, 1.0, 0.0, 0.0, 2.0, 0.5, -1.0];
    b.transform(3, 1, &m);
    let kf = b.finish().unwrap().unwrap();
    let mut rust = Decoder::new(Limits::default());
    rust.receive(&kf.bytes).unwrap();
    let c = decoder(None);
    receive(c, &kf.bytes).unwrap();
    let inst = rust.mirror().instance(3).unwrap();
    let affine = inst.transform().unwrap().affine();

    let mut positions = Vec::new();
    let mut normals = Vec::new();
    for i in 0..200 {
        let (p, n, _) = point(i * 2 + 1, 0);
        let p = p + Vec3::new(0.01, 0.02, -0.01);
        positions.extend(p.to_array());
        normals.extend(n.to_array());
        let want = reconstruct_ao(inst, p, n.normalize());
        let mut got = -1.0;
        let r = unsafe {
            psao_decoder_reconstruct(c, 3, p.to_array().as_ptr(), n.to_array().as_ptr(), &mut got)
        };
        assert_eq!(r, R::PSAO_OK);
        assert_eq!(got, want);
        // World space: the same point moved by the transform.
        let (pw, nw) = (affine.transform_point3(p), affine.transform_vector3(n));
        let r = unsafe {
            psao_decoder_reconstruct_world(
                c,
                3,
                pw.to_array().as_ptr(),
                nw.to_array().as_ptr(),
                &mut got,
            )
        };
        assert_eq!(r, R::PSAO_OK);
        assert!((got - want).abs() < 1e-3, "{got} {want}");
    }
    let mut many = vec![0f32; 200];
    let r = unsafe {
        psao_decoder_reconstruct_many(
            c,
            3,
            positions.as_ptr(),
            normals.as_ptr(),
            200,
            many.as_mut_ptr(),
        )
    };
    assert_eq!(r, R::PSAO_OK);
    for (k, got) in many.iter().enumerate() {
        let p = Vec3::from_slice(&positions[3 * k..]);
        let n = Vec3::from_slice(&normals[3 * k..]).normalize();
        assert_eq!(*got, reconstruct_ao(inst, p, n));
    }
    assert!(many.iter().any(|&a| a < 1.0), "some points are reached");
    unsafe { psao_decoder_free(c) };
}

#[test]
fn result_names_are_stable_and_cover_every_code() {
    assert_eq!(name(R::PSAO_OK), "ok");
    assert_eq!(name(R::PSAO_ERROR_BUFFER_TOO_SHORT), "buffer_too_short");
    assert_eq!(name(R::PSAO_ERROR_AO_TO_EMPTY_SLOT), "ao_to_empty_slot");
    let unknown = unsafe { std::ffi::CStr::from_ptr(psao_result_name(9999)) };
    assert_eq!(unknown.to_str().unwrap(), "unknown");
    let mut seen = 0;
    for v in 0..300u32 {
        if let Some(r) = psao_result::from_u32(v) {
            assert_eq!(psao_result::from_name(r.name()), Some(r));
            seen += 1;
        }
    }
    assert_eq!(seen, 50);
    assert_eq!(PSAO_WIRE_VERSION, psao_codec::wire::VERSION);
    let version = unsafe { std::ffi::CStr::from_ptr(psao_version()) };
    assert_eq!(version.to_str().unwrap(), env!("CARGO_PKG_VERSION"));
}

#[test]
fn a_bind_space_instance_is_looked_up_in_bind_space_only() {
    let mut d = def();
    d.point_format = psao_codec::POINT_FORMAT_BIND32;
    let kf = one_point_keyframe(d, None);
    let c = decoder(None);
    receive(c, &kf).unwrap();
    let (p, n) = ([0.1f32, 0.1, 0.1], [0.0f32, 1.0, 0.0]);
    let mut ao = -1.0;
    unsafe {
        assert_eq!(
            psao_decoder_reconstruct(c, 3, p.as_ptr(), n.as_ptr(), &mut ao),
            R::PSAO_OK
        );
        assert!((ao - 0.25).abs() < 1.0 / 255.0, "{ao}");
        assert_eq!(
            psao_decoder_reconstruct_world(c, 3, p.as_ptr(), n.as_ptr(), &mut ao),
            R::PSAO_ERROR_INVALID_ARGUMENT
        );
    }
    assert!(decoder_error(c).contains("bind space"));
    unsafe { psao_decoder_free(c) };
}

#[test]
fn the_normal_table_is_the_codecs() {
    let mut out = vec![0f32; 1024];
    let mut len = 0;
    let r = unsafe { psao_normal_table(out.as_mut_ptr(), 1000, &mut len) };
    assert_eq!((r, len), (R::PSAO_ERROR_BUFFER_TOO_SHORT, 1024));
    assert!(out.iter().all(|&f| f == 0.0));
    let r = unsafe { psao_normal_table(out.as_mut_ptr(), out.len(), &mut len) };
    assert_eq!(r, R::PSAO_OK);
    for (code, n) in psao_codec::normal_table().iter().enumerate() {
        assert_eq!(&out[4 * code..4 * code + 4], &[n.x, n.y, n.z, 0.0]);
    }
}

#[test]
fn world_lookups_of_an_instance_without_a_transform_are_open() {
    let kf = one_point_keyframe(def(), None);
    let c = decoder(None);
    receive(c, &kf).unwrap();
    let (p, n) = ([0.1f32, 0.1, 0.1], [0.0f32, 1.0, 0.0]);
    let (mut local, mut world) = (-1.0, -1.0);
    unsafe {
        assert_eq!(
            psao_decoder_reconstruct(c, 3, p.as_ptr(), n.as_ptr(), &mut local),
            R::PSAO_OK
        );
        assert_eq!(
            psao_decoder_reconstruct_world(c, 3, p.as_ptr(), n.as_ptr(), &mut world),
            R::PSAO_OK
        );
        psao_decoder_free(c);
    }
    assert!((local - 0.25).abs() < 1.0 / 255.0, "{local}");
    assert_eq!(world, 1.0, "no transform: no place in the world");
}

#[test]
fn object_less_failures_keep_their_message_per_thread() {
    let mut bad = c_def(&def());
    bad.cell_capacity = 0;
    let mut t = null_mut();
    let r = unsafe { psao_table_new(1, &bad, 10, null(), &mut t) };
    assert_eq!(r, R::PSAO_ERROR_INVALID_DEFINITION);
    let mut buf = vec![0u8; 256];
    let mut n = 0;
    assert_eq!(
        unsafe { psao_last_error(buf.as_mut_ptr().cast(), buf.len(), &mut n) },
        R::PSAO_OK
    );
    let msg = std::str::from_utf8(&buf[..n]).unwrap().to_string();
    assert!(msg.contains("cell capacity"), "{msg}");
    // Another thread has its own (empty) message.
    let other = std::thread::spawn(|| {
        let mut buf = [1u8; 4];
        let mut n = 9;
        let r = unsafe { psao_last_error(buf.as_mut_ptr().cast(), buf.len(), &mut n) };
        (r, n, buf[0])
    })
    .join()
    .unwrap();
    assert_eq!(other, (R::PSAO_OK, 0, 0));
    // A success clears it.
    let d = decoder(None);
    unsafe { psao_last_error(buf.as_mut_ptr().cast(), buf.len(), &mut n) };
    assert_eq!(n, 0);
    unsafe { psao_decoder_free(d) };
}

#[test]
fn abort_after_taking_changes_makes_clients_see_a_gap_and_keyframes_refuse_changes() {
    let (t, e) = (table(&def(), 500), encoder(&psao_encoder_config_default()));
    let d = decoder(None);
    unsafe {
        assert_eq!(psao_encoder_begin(e, 1), R::PSAO_OK);
        assert_eq!(psao_encoder_snapshot(e, t), R::PSAO_OK);
    }
    receive(d, &finish(e)).unwrap();
    set_points(t, 50, 0);
    unsafe {
        // Changes belong in deltas.
        assert_eq!(psao_encoder_begin(e, 1), R::PSAO_OK);
        assert_eq!(psao_encoder_changes(e, t), R::PSAO_ERROR_INVALID_ARGUMENT);
        assert_eq!(psao_encoder_abort(e), R::PSAO_OK);
        // A delta that took the table's changes, then aborted.
        assert_eq!(psao_encoder_begin(e, 0), R::PSAO_OK);
        assert_eq!(psao_encoder_changes(e, t), R::PSAO_OK);
        assert_eq!(psao_encoder_abort(e), R::PSAO_OK);
        let mut seq = 0;
        psao_encoder_sequence(e, &mut seq);
        assert_eq!(seq, 1, "the aborted delta took its sequence");
        let (p, n, _) = point(0, 0);
        psao_table_set_point(
            t,
            0,
            p.to_array().as_ptr(),
            n.to_array().as_ptr(),
            0.9,
            null_mut(),
        );
        assert_eq!(psao_encoder_begin(e, 0), R::PSAO_OK);
        assert_eq!(psao_encoder_changes(e, t), R::PSAO_OK);
    }
    let ev = receive(d, &finish(e)).unwrap();
    assert_eq!(ev.kind, psao_event_kind::PSAO_EVENT_NEED_KEYFRAME);
    assert_eq!((ev.have, ev.base), (0, 1));
    // The encoder's configuration changes between frames only.
    let mut cfg = psao_encoder_config_default();
    cfg.compression = 1;
    unsafe {
        assert_eq!(psao_encoder_set_config(e, &cfg), R::PSAO_OK);
        assert_eq!(psao_encoder_begin(e, 0), R::PSAO_OK);
        assert_eq!(psao_encoder_set_config(e, &cfg), R::PSAO_ERROR_FRAME_OPEN);
        cfg.compression = 5;
        assert_eq!(psao_encoder_abort(e), R::PSAO_OK);
        assert_eq!(
            psao_encoder_set_config(e, &cfg),
            R::PSAO_ERROR_INVALID_ARGUMENT
        );
        // Placement of a stored point, and of one never set.
        let mut pl = std::mem::MaybeUninit::<psao_placement>::uninit();
        assert_eq!(psao_table_placement(t, 0, pl.as_mut_ptr()), R::PSAO_OK);
        assert_eq!(
            pl.assume_init().kind,
            psao_placement_kind::PSAO_PLACEMENT_STORED
        );
        assert_eq!(psao_table_placement(t, 400, pl.as_mut_ptr()), R::PSAO_OK);
        assert_eq!(
            pl.assume_init().kind,
            psao_placement_kind::PSAO_PLACEMENT_ABSENT
        );
        psao_decoder_free(d);
        psao_table_free(t);
        psao_encoder_free(e);
    }
}

#[test]
fn outputs_need_no_alignment_and_non_finite_inputs_are_open() {
    let m = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0];
    let kf = one_point_keyframe(def(), Some(m));
    let c = decoder(None);
    receive(c, &kf).unwrap();
    // A u32 and a float written at odd addresses, read from odd addresses.
    let mut bytes = [0u8; 64];
    let odd = unsafe { bytes.as_mut_ptr().add(1) };
    let mut src = [0u8; 32];
    let p = unsafe { src.as_mut_ptr().add(1) }.cast::<f32>();
    unsafe {
        for (i, v) in [0.1f32, 0.1, 0.1, 0.0, 1.0, 0.0].iter().enumerate() {
            p.add(i).write_unaligned(*v);
        }
        assert_eq!(psao_decoder_sequence(c, odd.cast()), R::PSAO_OK);
        assert_eq!(odd.cast::<u32>().read_unaligned(), 0);
        assert_eq!(
            psao_decoder_reconstruct(c, 3, p, p.add(3), odd.cast()),
            R::PSAO_OK
        );
        let ao = odd.cast::<f32>().read_unaligned();
        assert!((ao - 0.25).abs() < 1.0 / 255.0, "{ao}");
        // A NaN normal is open, as in the shader, whatever T_n.
        p.add(4).write_unaligned(f32::NAN);
        let mut ao = 0.0;
        assert_eq!(
            psao_decoder_reconstruct(c, 3, p, p.add(3), &mut ao),
            R::PSAO_OK
        );
        assert_eq!(ao, 1.0);
        assert_eq!(
            psao_decoder_reconstruct_world(c, 3, p, p.add(3), &mut ao),
            R::PSAO_OK
        );
        assert_eq!(ao, 1.0);
        // A transform to an instance the mirror lacks: Rust's class.
        let t = psao_transform {
            sequence: 2,
            matrix: m,
        };
        let mut replaced = 0;
        assert_eq!(
            psao_decoder_apply_transform(c, 8, &t, &mut replaced),
            R::PSAO_ERROR_UNKNOWN_INSTANCE
        );
        psao_decoder_free(c);
    }
}

#[test]
fn the_gpu_record_maps_world_points_into_the_grid_like_the_cpu() {
    let m = [0.0, 0.0, -2.0, 0.0, 1.0, 0.0, 1.0, 0.0, 0.0, 2.0, 0.5, -1.0];
    let kf = one_point_keyframe(def(), Some(m));
    let c = decoder(None);
    receive(c, &kf).unwrap();
    let mut rec = [0u32; 48];
    unsafe {
        assert_eq!(
            psao_decoder_instance_gpu(c, 3, 100, 200, rec.as_mut_ptr()),
            R::PSAO_OK
        );
        assert_eq!(
            psao_decoder_instance_gpu(c, 4, 0, 0, rec.as_mut_ptr()),
            R::PSAO_ERROR_NOT_FOUND
        );
        psao_decoder_free(c);
    }
    let f = |i: usize| f32::from_bits(rec[i]);
    let col = |k: usize| Vec3::new(f(4 * k), f(4 * k + 1), f(4 * k + 2));
    let mut rust = Decoder::new(Limits::default());
    rust.receive(&kf).unwrap();
    let inst = rust.mirror().instance(3).unwrap();
    let affine = inst.transform().unwrap().affine();
    let local = Vec3::new(0.3, -0.2, 0.7);
    let world = affine.transform_point3(local);
    let back = col(0) * world.x + col(1) * world.y + col(2) * world.z + col(3);
    assert!((back - local).length() < 1e-5, "{back} {local}");
    assert_eq!(f(15), 1.0, "overflow chains");
    assert_eq!(&rec[36..44], &[8, 8, 8, 63, 8, 7, 100, 200]);
    assert_eq!((f(28), f(31)), (-1.0, def().radius));
    assert_eq!(
        (f(44), f(45), f(46), f(47)),
        (def().t_n, def().t_d, 1.0, 0.0)
    );
}
