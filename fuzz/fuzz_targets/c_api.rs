//! The C entry points driven as a C caller would, with fuzzed arguments:
//! the input is a program of operations on one decoder, one table and one
//! encoder (opcode byte, then the operation's arguments). Checks: no call
//! panics (a caught panic would return PSAO_ERROR_PANIC), every result is
//! a defined code, a short buffer is never written, a rejected frame
//! leaves the mirror's digest as it was, and every frame the encoder
//! finishes is well-formed (header, payload, messages).
#![no_main]

use std::ptr::{null, null_mut};

use libfuzzer_sys::fuzz_target;
use psao_codec::Limits;
use psao_codec::wire::{Scratch, decode_frame};
use psao_ffi::*;

/// Reads fuzzed arguments; zeros once the input is used up.
struct Args<'a>(&'a [u8]);

impl Args<'_> {
    fn u8(&mut self) -> u8 {
        let (&b, rest) = self.0.split_first().unwrap_or((&0, &[]));
        self.0 = rest;
        b
    }
    fn u16(&mut self) -> u16 {
        u16::from_le_bytes([self.u8(), self.u8()])
    }
    fn u32(&mut self) -> u32 {
        u32::from_le_bytes([self.u8(), self.u8(), self.u8(), self.u8()])
    }
    fn f32(&mut self) -> f32 {
        f32::from_bits(self.u32())
    }
    fn vec3(&mut self) -> [f32; 3] {
        [self.f32(), self.f32(), self.f32()]
    }
    fn bytes(&mut self, n: usize) -> &[u8] {
        let n = n.min(self.0.len());
        let (b, rest) = self.0.split_at(n);
        self.0 = rest;
        b
    }
}

fn defined(r: psao_result) {
    assert_ne!(r, psao_result::PSAO_ERROR_PANIC, "a panic reached the boundary");
    assert!(psao_result::from_u32(r as u32).is_some());
}

fn digest(d: *mut psao_decoder) -> Option<u32> {
    let mut v = 0;
    // SAFETY: `d` is a live decoder, `v` a live local.
    (unsafe { psao_decoder_digest(d, &mut v) } == psao_result::PSAO_OK).then_some(v)
}

const FILL: u8 = 0xA5;

fuzz_target!(|data: &[u8]| {
    let limits = psao_limits {
        max_payload_bytes: 1 << 16,
        max_mirror_bytes: 1 << 18,
        max_instances: 16,
        max_cell_pool: 1 << 12,
        max_table_log2: 10,
        ..psao_limits_default()
    };
    let mut args = Args(data);
    let mut d = null_mut();
    // SAFETY: `limits` and `d` are live locals.
    assert_eq!(unsafe { psao_decoder_new(&limits, &mut d) }, psao_result::PSAO_OK);
    let mut table: *mut psao_table = null_mut();
    let mut enc: *mut psao_encoder = null_mut();
    let mut out = vec![FILL; 1 << 16];

    while !args.0.is_empty() {
        match args.u8() % 12 {
            0 => {
                let len = args.u16() as usize;
                let frame = args.bytes(len).to_vec();
                let before = digest(d);
                let mut ev = std::mem::MaybeUninit::<psao_event>::uninit();
                // SAFETY: `frame` holds `frame.len()` bytes; `ev` is writable.
                let r = unsafe { psao_decoder_receive(d, frame.as_ptr(), frame.len(), ev.as_mut_ptr()) };
                defined(r);
                if r != psao_result::PSAO_OK {
                    assert_eq!(before, digest(d), "a rejected frame changed the mirror");
                }
            }
            1 => {
                let (id, first, count) = (args.u8() as u32, args.u32() % 70_000, args.u16() as usize);
                let cap = count.min(out.len() / 4);
                let mut words = vec![0xA5A5_A5A5u32; cap];
                // SAFETY: `words` holds `cap` words.
                let r = unsafe { psao_decoder_copy_words(d, id, first, cap, words.as_mut_ptr()) };
                defined(r);
                if r != psao_result::PSAO_OK {
                    assert!(words.iter().all(|&w| w == 0xA5A5_A5A5));
                }
            }
            2 => {
                let cap = args.u8() as usize;
                let mut items = vec![
                    psao_change { kind: psao_change_kind::PSAO_CHANGE_DEFINED, instance: 7, start: 7, end: 7 };
                    cap
                ];
                let (mut len, mut all) = (0, 0);
                // SAFETY: `items` holds `cap` entries; `len`, `all` are locals.
                let r = unsafe { psao_decoder_changes(d, items.as_mut_ptr(), cap, &mut len, &mut all) };
                defined(r);
                if r == psao_result::PSAO_ERROR_BUFFER_TOO_SHORT {
                    assert!(len > cap && items.iter().all(|c| c.instance == 7 && c.start == 7));
                }
                if args.u8() & 1 == 1 {
                    // SAFETY: live decoder.
                    defined(unsafe { psao_decoder_clear_changes(d) });
                }
            }
            3 => {
                let id = args.u8() as u32;
                let (p, n) = (args.vec3(), args.vec3());
                let mut ao = 0.0f32;
                let world = args.u8() & 1 == 1;
                // SAFETY: `p`, `n` hold 3 floats; `ao` is a local.
                let r = unsafe {
                    if world {
                        psao_decoder_reconstruct_world(d, id, p.as_ptr(), n.as_ptr(), &mut ao)
                    } else {
                        psao_decoder_reconstruct(d, id, p.as_ptr(), n.as_ptr(), &mut ao)
                    }
                };
                defined(r);
                if r == psao_result::PSAO_OK {
                    assert!((0.0..=1.0).contains(&ao), "AO {ao}");
                }
            }
            4 => {
                let id = args.u8() as u32;
                let t = psao_transform { sequence: args.u32(), matrix: std::array::from_fn(|_| args.f32()) };
                let mut replaced = 0;
                // SAFETY: `t` and `replaced` are locals.
                defined(unsafe { psao_decoder_apply_transform(d, id, &t, &mut replaced) });
            }
            5 => {
                let cap = args.u8() as usize;
                let mut buf = vec![FILL; cap];
                let mut len = 0;
                // SAFETY: `buf` holds `cap` bytes.
                let r = unsafe { psao_decoder_last_error(d, buf.as_mut_ptr().cast(), cap, &mut len) };
                defined(r);
                if r == psao_result::PSAO_OK {
                    assert_eq!(buf[len], 0);
                } else {
                    assert!(buf.iter().all(|&b| b == FILL));
                }
            }
            6 => {
                // A table from fuzzed definition bytes.
                // SAFETY: `table` is NULL or live.
                unsafe { psao_table_free(table) };
                table = null_mut();
                let def = psao_instance_def {
                    origin: args.vec3(),
                    cell_size: args.vec3(),
                    dims: [args.u8() as u32, args.u8() as u32, args.u8() as u32],
                    table_log2: args.u8(),
                    bucket_capacity: args.u8(),
                    cell_capacity: args.u8(),
                    point_format: args.u8() % 3,
                    overflow: args.u8() % 3,
                    cell_pool: args.u16() as u32,
                    radius: args.f32(),
                    t_n: args.f32(),
                    t_d: args.f32(),
                };
                // SAFETY: `def`, `limits`, `table` are locals.
                let r = unsafe { psao_table_new(args.u8() as u32 % 4, &def, 4096, &limits, &mut table) };
                defined(r);
                assert_eq!(r == psao_result::PSAO_OK, !table.is_null());
            }
            7 => {
                let (id, p, n, ao) = (args.u16() as u32, args.vec3(), args.vec3(), args.f32());
                let mut placement = std::mem::MaybeUninit::<psao_placement>::uninit();
                let mut sent = 0;
                // SAFETY: `table` is NULL (refused) or live; the rest are locals.
                let r = unsafe {
                    if args.u8() & 1 == 0 {
                        psao_table_set_point(table, id, p.as_ptr(), n.as_ptr(), ao, placement.as_mut_ptr())
                    } else {
                        psao_table_update_point(table, id, p.as_ptr(), n.as_ptr(), ao, null(), &mut sent)
                    }
                };
                defined(r);
            }
            8 => {
                if enc.is_null() {
                    let mut cfg = psao_encoder_config_default();
                    cfg.compression = args.u8() as u32 % 4;
                    cfg.checksum = args.u8() % 2;
                    cfg.limits = limits;
                    // SAFETY: `cfg`, `enc` are locals.
                    defined(unsafe { psao_encoder_new(&cfg, args.u32(), &mut enc) });
                } else {
                    // SAFETY: live encoder.
                    defined(unsafe { psao_encoder_begin(enc, args.u8() % 3) });
                }
            }
            9 => {
                // SAFETY: `enc` and `table` are NULL (refused) or live.
                let r = unsafe {
                    match args.u8() % 5 {
                        0 => psao_encoder_changes(enc, table),
                        1 => psao_encoder_snapshot(enc, table),
                        2 => psao_encoder_remove_instance(enc, args.u8() as u32 % 4),
                        3 => {
                            let t = psao_transform {
                                sequence: args.u32(),
                                matrix: std::array::from_fn(|_| args.f32()),
                            };
                            psao_encoder_transform(enc, args.u8() as u32 % 4, &t)
                        }
                        _ => psao_encoder_abort(enc),
                    }
                };
                defined(r);
            }
            10 => {
                let cap = (args.u16() as usize).min(out.len());
                out.fill(FILL);
                let mut len = 0;
                // SAFETY: `out` holds at least `cap` bytes.
                let r = unsafe { psao_encoder_finish(enc, out.as_mut_ptr(), cap, &mut len, null_mut()) };
                defined(r);
                if r == psao_result::PSAO_ERROR_BUFFER_TOO_SHORT {
                    assert!(len > cap && out.iter().all(|&b| b == FILL));
                }
                if r == psao_result::PSAO_OK && len > 0 {
                    // The encoder's frames are well-formed: header,
                    // payload and every message parse. (Whether they
                    // apply depends on what a client saw before, which
                    // a fuzzed program does not keep consistent.)
                    let mut scratch = Scratch::default();
                    let view = decode_frame(&out[..len], &Limits::default(), &mut scratch)
                        .unwrap_or_else(|e| panic!("the encoder wrote a bad frame: {e}"));
                    for m in view.messages() {
                        if let Err(e) = m {
                            panic!("the encoder wrote a bad message: {e}");
                        }
                    }
                }
            }
            _ => {
                let mut seq = 0;
                // SAFETY: live decoder, local output.
                defined(unsafe { psao_decoder_sequence(d, &mut seq) });
                let mut n = 0;
                // SAFETY: live decoder; cap 0 with NULL.
                defined(unsafe { psao_decoder_instance_ids(d, null_mut(), 0, &mut n) });
            }
        }
    }
    // SAFETY: each is NULL or live, freed once.
    unsafe {
        psao_decoder_free(d);
        psao_table_free(table);
        psao_encoder_free(enc);
    }
});
