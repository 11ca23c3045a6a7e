//! GridTable: allocation, compaction, moves, frees, and counted overflow.

mod common;

use common::{assert_chains_compacted, small_def};
use glam::{UVec3, Vec3};
use psao_codec::wire::point::quantize_ao;
use psao_codec::*;

fn centre(def: &InstanceDef, cell: UVec3) -> Vec3 {
    def.cell_min(cell) + def.cell_size * 0.5
}

#[test]
fn insert_move_remove_keep_compaction_and_free_cells() {
    let def = small_def();
    let mut t = GridTable::new(1, def, 16).unwrap();
    let a = centre(&def, UVec3::new(1, 1, 1));
    let b = centre(&def, UVec3::new(5, 2, 3));
    for id in 0..3 {
        t.set_point(id, a, Vec3::Y, 0.5).unwrap();
    }
    assert_eq!(t.placement(0), Placement::Stored { cell: 0, slot: 0 });
    assert_eq!(t.placement(2), Placement::Stored { cell: 0, slot: 2 });
    let dirty = t.take_dirty();
    assert_eq!(dirty.cells.len(), 1);
    assert_eq!(
        dirty.buckets,
        vec![def.bucket_of_key(def.key(UVec3::new(1, 1, 1)))]
    );

    // Removing slot 0 moves the last point into the hole.
    assert!(t.remove_point(0));
    assert_eq!(t.placement(2), Placement::Stored { cell: 0, slot: 0 });
    assert_eq!(t.cell_len(0), 2);
    assert_eq!(t.cell(0)[2], 0);

    // Moving both points elsewhere frees cell 0 and its bucket entry.
    t.set_point(1, b, Vec3::Y, 0.5).unwrap();
    t.set_point(2, b, Vec3::Y, 0.5).unwrap();
    assert_eq!(t.stats().cells, 1);
    assert!(
        t.bucket(def.bucket_of_key(def.key(UVec3::new(1, 1, 1))))
            .is_empty()
    );
    assert!(t.cell(0).iter().all(|&w| w == 0));
    assert_eq!(t.stats().stored, 2);
    assert!(!t.remove_point(0), "already removed");
}

#[test]
fn cell_overflow_is_counted_and_retried() {
    let def = small_def();
    let mut t = GridTable::new(1, def, 16).unwrap();
    let a = centre(&def, UVec3::new(2, 2, 2));
    for id in 0..9 {
        t.set_point(id, a, Vec3::Y, 0.5).unwrap();
    }
    assert_eq!(t.stats().stored, 7);
    assert_eq!(t.stats().cell_overflow, 2);
    assert_eq!(t.placement(8), Placement::Dropped(DropReason::CellFull));
    assert_eq!(t.stats().dropped, 2);
    // Room frees up; the dropped point's next update stores it.
    t.remove_point(0);
    t.set_point(8, a, Vec3::Y, 0.5).unwrap();
    assert!(matches!(t.placement(8), Placement::Stored { .. }));
    assert_eq!(t.stats().dropped, 1);
    assert!(!t.remove_point(7), "point 7 is dropped, not stored");
    assert_eq!(t.stats().dropped, 0);
}

/// With overflow chains a crowded cell keeps every point up to 17 links of
/// `cell_capacity`, drops only past that, and stays compacted as points
/// leave from any link (the chain's last point fills the hole).
#[test]
fn overflow_chains_hold_a_crowded_cell_and_stay_compacted() {
    let def = InstanceDef {
        cell_capacity: 2,
        overflow: true,
        ..small_def()
    };
    let cap = def.cell_capacity as u32;
    let total = (MAX_OVERFLOW_LINKS as u32 + 1) * cap;
    let mut t = GridTable::new(1, def, 64).unwrap();
    let a = centre(&def, UVec3::new(2, 2, 2));
    for id in 0..total + 3 {
        t.set_point(id, a, Vec3::Y, id as f32 / 64.0).unwrap();
    }
    assert_eq!(t.stats().stored, total);
    assert_eq!(t.stats().cells, MAX_OVERFLOW_LINKS as u32 + 1);
    assert_eq!(t.stats().dropped, 3);
    assert_eq!(t.placement(total), Placement::Dropped(DropReason::CellFull));
    assert_chains_compacted(&t);
    // Points leave from the first, a middle and the last link: the chain
    // shrinks from its end, and the dropped points get in again.
    for id in [0, 13, total - 1, 5, 6, 7] {
        assert!(t.remove_point(id));
        assert_chains_compacted(&t);
    }
    assert_eq!(t.stats().stored, total - 6);
    assert_eq!(t.stats().cells, (total - 6).div_ceil(cap));
    for id in total..total + 3 {
        t.set_point(id, a, Vec3::Y, 0.5).unwrap();
        assert!(matches!(t.placement(id), Placement::Stored { .. }));
    }
    assert_chains_compacted(&t);
    // Every stored point's slot holds its own word (the moved ones too).
    for id in (0..total + 3).filter(|id| ![0, 13, total - 1, 5, 6, 7].contains(id)) {
        let Placement::Stored { cell, slot } = t.placement(id) else {
            panic!("point {id} not stored");
        };
        let ao = if id >= total { 0.5 } else { id as f32 / 64.0 };
        let w = PointWord(t.cell(cell)[slot as usize]);
        assert_eq!(w.fields().ao, quantize_ao(ao), "point {id}");
    }
    // Without chains the same cell drops all but its own 2 slots.
    let mut flat = GridTable::new(
        1,
        InstanceDef {
            overflow: false,
            ..def
        },
        64,
    )
    .unwrap();
    for id in 0..total {
        flat.set_point(id, a, Vec3::Y, 0.5).unwrap();
    }
    assert_eq!(flat.stats().stored, cap);
    assert_eq!(flat.stats().dropped, total - cap);
}

#[test]
fn bucket_overflow_and_pool_exhaustion_are_counted() {
    let def = InstanceDef {
        table_log2: 0,
        bucket_capacity: 2,
        cell_pool: 8,
        ..small_def()
    };
    let mut t = GridTable::new(1, def, 16).unwrap();
    for (id, x) in (0..4).enumerate() {
        t.set_point(id as u32, centre(&def, UVec3::new(x, 0, 0)), Vec3::Y, 1.0)
            .unwrap();
    }
    assert_eq!(t.stats().bucket_overflow, 2);
    assert_eq!(t.placement(3), Placement::Dropped(DropReason::BucketFull));

    let def = InstanceDef {
        cell_pool: 2,
        ..small_def()
    };
    let mut t = GridTable::new(1, def, 16).unwrap();
    for (id, x) in (0..3).enumerate() {
        t.set_point(id as u32, centre(&def, UVec3::new(x, 0, 0)), Vec3::Y, 1.0)
            .unwrap();
    }
    assert_eq!(t.stats().pool_exhausted, 1);
    assert_eq!(
        t.placement(2),
        Placement::Dropped(DropReason::PoolExhausted)
    );
}

#[test]
fn out_of_grid_points_are_dropped_and_counted() {
    let def = small_def();
    let mut t = GridTable::new(1, def, 16).unwrap();
    t.set_point(0, centre(&def, UVec3::ZERO), Vec3::Y, 1.0)
        .unwrap();
    for p in [
        Vec3::splat(100.0),
        Vec3::splat(-1.01),
        Vec3::NAN,
        Vec3::INFINITY,
    ] {
        assert_eq!(
            t.set_point(0, p, Vec3::Y, 1.0).unwrap(),
            Placement::Dropped(DropReason::OutOfGrid)
        );
    }
    assert_eq!(t.stats().out_of_grid, 4);
    assert_eq!(t.stats().stored, 0);
    assert_eq!(t.stats().cells, 0);
}

#[test]
fn point_ids_are_bounded() {
    let mut t = GridTable::new(1, small_def(), 16).unwrap();
    assert_eq!(
        t.set_point(16, Vec3::ZERO, Vec3::Y, 1.0),
        Err(EncodeError::PointId { id: 16, limit: 16 })
    );
}

#[test]
fn invalid_definitions_are_refused() {
    let bad = [
        (
            InstanceDef {
                dims: UVec3::new(1000, 1000, 200),
                ..small_def()
            },
            DefError::Dims,
        ),
        (
            InstanceDef {
                dims: UVec3::new(0, 1, 1),
                ..small_def()
            },
            DefError::Dims,
        ),
        (
            InstanceDef {
                cell_size: Vec3::new(1.0, 0.0, 1.0),
                ..small_def()
            },
            DefError::CellSize,
        ),
        (
            InstanceDef {
                origin: Vec3::NAN,
                ..small_def()
            },
            DefError::NonFinite,
        ),
        (
            InstanceDef {
                cell_capacity: 9,
                ..small_def()
            },
            DefError::CellCapacity,
        ),
        (
            InstanceDef {
                bucket_capacity: 0,
                ..small_def()
            },
            DefError::BucketCapacity,
        ),
        (
            InstanceDef {
                table_log2: 32,
                ..small_def()
            },
            DefError::TableSize,
        ),
        (
            InstanceDef {
                cell_pool: 0,
                ..small_def()
            },
            DefError::CellPool,
        ),
        (
            InstanceDef {
                point_format: 2,
                overflow: false,
                ..small_def()
            },
            DefError::PointFormat,
        ),
        (
            InstanceDef {
                radius: 0.0,
                ..small_def()
            },
            DefError::Reconstruction,
        ),
    ];
    for (def, err) in bad {
        assert_eq!(
            GridTable::new(1, def, 1).unwrap_err(),
            EncodeError::Def(err)
        );
    }
}

#[test]
fn key_is_eq1_unique_and_fits() {
    let def = InstanceDef {
        dims: UVec3::new(7, 5, 3),
        ..small_def()
    };
    let mut seen = std::collections::HashSet::new();
    for z in 0..3 {
        for y in 0..5 {
            for x in 0..7 {
                let c = UVec3::new(x, y, z);
                let k = def.key(c);
                assert_eq!(k, x + y * 7 * 17 + z * 7 * 5 * 31);
                assert!(seen.insert(k));
                assert_eq!(def.cell_of_key(k), Some(c));
            }
        }
    }
    // Every other key below the bound names no cell.
    let named = (0..31 * 7 * 5 * 3)
        .filter(|&k| def.cell_of_key(k).is_some())
        .count();
    assert_eq!(named, 105);
    // floor((2^32 - 1) / 31) = 138_547_332 cells at most.
    assert!(key_fits(UVec3::new(138_547_332, 1, 1)));
    assert!(!key_fits(UVec3::new(138_547_333, 1, 1)));
    assert!(key_fits(UVec3::new(2, 2, 34_636_833)));
    assert!(!key_fits(UVec3::new(2, 2, 34_636_834)));
    // The largest allowed grid keeps its largest key below EMPTY_KEY.
    let big = InstanceDef {
        dims: UVec3::new(138_547_332, 1, 1),
        ..small_def()
    };
    assert!(big.validate().is_ok());
    assert!(big.key(UVec3::new(138_547_331, 0, 0)) < EMPTY_KEY);
}

#[test]
fn a_change_into_fully_open_updates_whatever_its_size() {
    let def = small_def();
    let mut t = GridTable::new(1, def, 4).unwrap();
    let th = Thresholds::default();
    let p = centre(&def, UVec3::new(3, 1, 3));
    assert!(t.update_point(0, p, Vec3::Y, 250.0 / 255.0, &th).unwrap());
    // Within the threshold, short of open: not sent.
    assert!(!t.update_point(0, p, Vec3::Y, 254.0 / 255.0, &th).unwrap());
    // Open (255 once quantized), 5 steps from what clients hold: sent.
    assert!(t.update_point(0, p, Vec3::Y, 0.9999, &th).unwrap());
    assert_eq!(t.sent(0, p, Vec3::Y).word.fields().ao, 255);
    // Open again, or within the threshold below open: nothing to send.
    assert!(!t.update_point(0, p, Vec3::Y, 1.0, &th).unwrap());
    assert!(!t.update_point(0, p, Vec3::Y, 250.0 / 255.0, &th).unwrap());
    // A zero threshold sends every change, open or not.
    let every = Thresholds { ao_steps: 0, ..th };
    assert!(
        t.update_point(0, p, Vec3::Y, 250.0 / 255.0, &every)
            .unwrap()
    );
    assert!(t.update_point(0, p, Vec3::Y, 1.0, &every).unwrap());
    // Open where clients hold open: nothing changed.
    assert!(!t.update_point(0, p, Vec3::Y, 1.0, &every).unwrap());
}

#[test]
fn update_point_applies_paper_thresholds() {
    let def = small_def();
    let mut t = GridTable::new(1, def, 4).unwrap();
    let th = Thresholds::default();
    let p = centre(&def, UVec3::new(3, 1, 3));
    assert!(
        t.update_point(0, p, Vec3::Y, 0.5, &th).unwrap(),
        "first set always updates"
    );
    let quantum = def.cell_size.x / 32.0;
    assert!(
        !t.update_point(0, p + Vec3::X * 2.0 * quantum, Vec3::Y, 0.5, &th)
            .unwrap()
    );
    let p = p + Vec3::X * 3.6 * quantum;
    assert!(t.update_point(0, p, Vec3::Y, 0.5, &th).unwrap());
    assert!(
        !t.update_point(0, p, Vec3::Y, 0.5 + 8.0 / 255.0, &th)
            .unwrap()
    );
    assert!(
        t.update_point(0, p, Vec3::Y, 0.5 + 9.0 / 255.0, &th)
            .unwrap()
    );
    let tilted = Vec3::new(0.7, 0.71, 0.0); // cos ~ 0.7 to +Y
    assert!(
        !t.update_point(0, p, tilted, 0.5 + 9.0 / 255.0, &th)
            .unwrap()
    );
    assert!(
        t.update_point(0, p, Vec3::X, 0.5 + 9.0 / 255.0, &th)
            .unwrap()
    );
    // Moving to another cell always updates, however small the step.
    let edge = def.cell_min(UVec3::new(4, 1, 3));
    assert!(
        t.update_point(0, edge - Vec3::X * 1e-4, Vec3::X, 0.53, &th)
            .unwrap()
    );
    assert!(
        t.update_point(0, edge + Vec3::X * 1e-4, Vec3::X, 0.53, &th)
            .unwrap()
    );
}
