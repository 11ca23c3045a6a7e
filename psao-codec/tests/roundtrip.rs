//! Any valid frame sequence decodes to the state the server holds: after
//! every frame, each mirror equals its GridTable.

mod common;

use common::*;
use glam::Vec3;
use proptest::prelude::*;
use psao_codec::wire::sequence;
use psao_codec::*;

#[derive(Clone, Debug)]
enum Op {
    Set {
        table: usize,
        id: u32,
        pos: [f32; 3],
        normal: [f32; 3],
        ao: f32,
    },
    Nudge {
        table: usize,
        id: u32,
        ao: f32,
    },
    Remove {
        table: usize,
        id: u32,
    },
    Transform {
        table: usize,
        seq: u32,
        t: f32,
    },
    Frame {
        compression: u8,
        checksum: bool,
        zstd_level: i32,
    },
    LateJoin,
}

fn op() -> impl Strategy<Value = Op> {
    let table = 0usize..2;
    let id = 0u32..120;
    prop_oneof![
        6 => (table.clone(), id.clone(), prop::array::uniform3(-1.2f32..1.2), prop::array::uniform3(-1.0f32..1.0), 0.0f32..=1.0)
            .prop_map(|(table, id, pos, normal, ao)| Op::Set { table, id, pos, normal, ao }),
        3 => (table.clone(), id.clone(), 0.0f32..=1.0).prop_map(|(table, id, ao)| Op::Nudge { table, id, ao }),
        2 => (table.clone(), id).prop_map(|(table, id)| Op::Remove { table, id }),
        1 => (table, 0u32..4, -5.0f32..5.0).prop_map(|(table, seq, t)| Op::Transform { table, seq, t }),
        2 => (0u8..3, any::<bool>(), 1i32..6).prop_map(|(compression, checksum, zstd_level)| Op::Frame { compression, checksum, zstd_level }),
        1 => Just(Op::LateJoin),
    ]
}

fn grid(table_log2: u8, cell_pool: u32, cell_capacity: u8, overflow: bool) -> InstanceDef {
    InstanceDef {
        table_log2,
        cell_pool,
        cell_capacity,
        overflow,
        ..small_def()
    }
}

fn check_all(decoders: &[Decoder], tables: &[GridTable], transforms: &[Option<(u32, [f32; 12])>]) {
    for d in decoders {
        for (t, tr) in tables.iter().zip(transforms) {
            assert_mirrors(d, t);
            assert_chains_compacted(t);
            let got = d
                .mirror()
                .instance(t.id())
                .unwrap()
                .transform()
                .map(|x| (x.sequence, x.matrix));
            assert_eq!(got, *tr);
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(1000))]

    #[test]
    fn mirror_equals_table_after_every_frame(
        ops in prop::collection::vec(op(), 1..120),
        log2 in 0u8..7,
        pool in 3u32..200,
        cap in 1u8..=8,
        overflow in any::<bool>(),
    ) {
        let mut tables = vec![
            GridTable::new(3, grid(log2, pool, cap, overflow), 120).unwrap(),
            GridTable::new(900, grid(6, 256, 7, overflow), 120).unwrap(),
        ];
        let mut transforms: Vec<Option<(u32, [f32; 12])>> = vec![None, None];
        let mut enc = Encoder::new(EncoderConfig::default());
        let mut decoders = vec![Decoder::new(Limits::default())];
        let kf = keyframe(&mut enc, &[&tables[0], &tables[1]]);
        let applied = matches!(decoders[0].receive(&kf.bytes), Ok(Event::Applied { keyframe: true, .. }));
        prop_assert!(applied);
        let mut pending_transforms: Vec<(usize, u32, [f32; 12])> = Vec::new();
        for op in ops {
            match op {
                Op::Set { table, id, pos, normal, ao } => {
                    tables[table].set_point(id, Vec3::from(pos), Vec3::from(normal), ao).unwrap();
                }
                Op::Nudge { table, id, ao } => {
                    if let Placement::Stored { cell, slot } = tables[table].placement(id) {
                        let cap = tables[table].def().cell_capacity as usize;
                        let w = PointWord(tables[table].words()[cell as usize * cap + slot as usize]);
                        let def = *tables[table].def();
                        let key_cell = (0..def.table_size())
                            .flat_map(|b| tables[table].bucket(b).to_vec())
                            .find(|e| e.cell == cell)
                            .and_then(|e| def.link_of_key(e.key))
                            .map(|(cell, _link)| cell)
                            .unwrap();
                        let pos = def.cell_min(key_cell) + w.frac() * def.cell_size;
                        tables[table].set_point(id, pos, w.normal(), ao).unwrap();
                    }
                }
                Op::Remove { table, id } => {
                    tables[table].remove_point(id);
                }
                Op::Transform { table, seq, t } => {
                    let m = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, t, 0.0, -t];
                    pending_transforms.push((table, seq, m));
                }
                Op::Frame { compression, checksum, zstd_level } => {
                    let compression = [Compression::None, Compression::Lz4, Compression::Zstd][compression as usize];
                    enc.set_config(EncoderConfig { compression, checksum, zstd_level, ..Default::default() });
                    let before = enc.sequence();
                    let mut f = enc.delta();
                    for (table, seq, m) in pending_transforms.drain(..) {
                        f.transform(tables[table].id(), seq, &m);
                        let newer = transforms[table].is_none_or(|(s, _)| sequence::is_newer(seq, s));
                        if newer {
                            transforms[table] = Some((seq, m));
                        }
                    }
                    for t in tables.iter_mut() {
                        f.changes(t);
                    }
                    match f.finish().unwrap() {
                        None => prop_assert_eq!(enc.sequence(), before),
                        Some(frame) => {
                            prop_assert_eq!(frame.sequence, before.wrapping_add(1));
                            for d in decoders.iter_mut() {
                                let e = d.receive(&frame.bytes).unwrap();
                                prop_assert_eq!(e, Event::Applied { sequence: frame.sequence, keyframe: false });
                            }
                        }
                    }
                    check_all(&decoders, &tables, &transforms);
                }
                Op::LateJoin => {
                    // A keyframe needs every change sent: flush a delta first.
                    let mut f = enc.delta();
                    for (table, seq, m) in pending_transforms.drain(..) {
                        f.transform(tables[table].id(), seq, &m);
                        if transforms[table].is_none_or(|(s, _)| sequence::is_newer(seq, s)) {
                            transforms[table] = Some((seq, m));
                        }
                    }
                    for t in tables.iter_mut() {
                        f.changes(t);
                    }
                    if let Some(frame) = f.finish().unwrap() {
                        for d in decoders.iter_mut() {
                            d.receive(&frame.bytes).unwrap();
                        }
                    }
                    let mut kf = enc.keyframe();
                    for (t, tr) in tables.iter().zip(&transforms) {
                        kf.snapshot(t).unwrap();
                        if let Some((seq, m)) = tr {
                            kf.transform(t.id(), *seq, m);
                        }
                    }
                    let kf = kf.finish().unwrap().unwrap();
                    prop_assert_eq!(kf.sequence, enc.sequence());
                    let mut late = Decoder::new(Limits::default());
                    prop_assert_eq!(late.receive(&kf.bytes).unwrap(), Event::Applied { sequence: kf.sequence, keyframe: true });
                    // An in-sync decoder may take the same keyframe too.
                    let applied = matches!(decoders[0].receive(&kf.bytes).unwrap(), Event::Applied { .. });
                    prop_assert!(applied);
                    decoders.push(late);
                    check_all(&decoders, &tables, &transforms);
                }
            }
        }
        // Stored points plus drops account for every stored point.
        for t in &tables {
            let s = t.stats();
            let stored = (0..t.def().cell_pool).map(|c| t.cell_len(c) as u32).sum::<u32>();
            prop_assert_eq!(s.stored, stored);
            let dropped = (0..120).filter(|&i| matches!(t.placement(i), Placement::Dropped(_))).count() as u32;
            prop_assert_eq!(s.dropped, dropped);
            prop_assert_eq!(s.cells, (0..t.def().cell_pool).filter(|&c| t.cell_len(c) > 0).count() as u32);
        }
    }
}
