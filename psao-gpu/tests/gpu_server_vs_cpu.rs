//! The server half on the GPU against the CPU backend on the same points
//! with the same sample sequence: point AO (both estimators, alpha masks,
//! deforming meshes), the comparison with what clients hold, and a whole
//! pipeline. These tests need a Vulkan adapter with ray queries (lavapipe
//! on a machine without a GPU). Without one they say so and pass, unless
//! `PSAO_REQUIRE_GPU` is set (CI sets it: there they must run).

mod common;

use common::{agreement, context, solid_default_scene};
use glam::Vec3;
use psao_eval::PosedScene;
use psao_gpu::*;
use psao_scene::*;
use psao_tests::scenes::{pipeline, world_points};

/// The pipeline's default rays per point.
fn default_rays() -> u32 {
    PipelineConfig::default().ao.rays
}

#[test]
fn gpu_ao_matches_the_cpu_backend_with_both_estimators_and_any_ray_count() {
    let Some(ctx) = context() else { return };
    // The whole default scene: rigid, skinned and alpha-masked instances.
    let scene = default_scene();
    let p = pipeline(&scene, 16.0, default_rays());
    let (ids, pts, nrm) = world_points(&p);
    assert!(pts.len() > 2000, "{} points", pts.len());
    let cpu_tracer = PosedScene::new(&scene, 0.0).unwrap().tracer();
    let gpu_scene = GpuScene::new(&ctx, &scene).unwrap();
    let ao = GpuAo::new(&ctx).unwrap();
    // Every fifth point not finite: such points (AO 1, nothing traced)
    // share workgroups with traced ones.
    let mut mixed = pts.clone();
    for (k, p) in mixed.iter_mut().enumerate().filter(|(k, _)| k % 5 == 0) {
        *p = if k % 10 == 0 {
            Vec3::NAN
        } else {
            Vec3::new(1.0, f32::INFINITY, 2.0)
        };
    }
    // 32 rays; and as the AO pass splits a point's rays over eight
    // invocations: no rays, fewer rays than lanes, counts that leave the
    // last round part-filled, and points that trace nothing beside points
    // that do.
    for (rays, pts) in [
        (32, &pts),
        (0, &pts),
        (1, &pts),
        (3, &pts),
        (8, &pts),
        (13, &pts),
        (13, &mixed),
    ] {
        for estimator in [Estimator::ClosestHit, Estimator::LaineKarras] {
            let params = AoParams {
                rays,
                estimator,
                ..AoParams::default()
            };
            let cpu = cpu_tracer.trace_ids(&ids, pts, &nrm, &params).unwrap();
            let gpu = ao
                .trace_ids(&ctx, &gpu_scene, &ids, pts, &nrm, &params)
                .unwrap();
            assert_eq!(cpu.rays, gpu.rays);
            let (share, worst) = agreement(&cpu.ao, &gpu.ao);
            eprintln!(
                "{rays} rays, {estimator:?}: {} points, {:.4}% within 1/255, worst {worst}",
                pts.len(),
                share * 100.0
            );
            assert!(
                share >= 0.999,
                "{rays} rays, {estimator:?}: only {:.3}% of points within 1/255 (worst {worst})",
                share * 100.0
            );
            for (k, p) in pts.iter().enumerate() {
                if rays == 0 || !p.is_finite() {
                    assert_eq!(gpu.ao[k], 1.0, "{rays} rays: point {k} at {p}");
                }
            }
        }
    }
}

#[test]
fn single_rays_add_up_to_the_gpus_point_ao_bit_for_bit_and_bad_jobs_are_errors() {
    let Some(ctx) = context() else { return };
    let scene = default_scene();
    let p = pipeline(&scene, 16.0, default_rays());
    let (ids, mut pts, nrm) = world_points(&p);
    // Some points with nothing to trace from: each of their rays scores 1.
    for (k, p) in pts.iter_mut().enumerate().filter(|(k, _)| k % 97 == 0) {
        *p = if k % 2 == 0 {
            Vec3::NAN
        } else {
            Vec3::INFINITY
        };
    }
    let n = pts.len();
    let cpu_tracer = PosedScene::new(&scene, 0.0).unwrap().tracer();
    let gpu_scene = GpuScene::new(&ctx, &scene).unwrap();
    let ao = GpuAo::new(&ctx).unwrap();
    for (rays, estimator) in [
        (32, Estimator::ClosestHit),
        (13, Estimator::ClosestHit),
        (13, Estimator::LaineKarras),
    ] {
        let params = AoParams {
            rays,
            estimator,
            ..AoParams::default()
        };
        // Every ray of every point, in a scrambled order; with 32 rays
        // every job twice over as well, past one dispatch's jobs.
        let mut jobs: Vec<RayJob> = (0..n as u32)
            .flat_map(|point| (0..rays).map(move |ray| RayJob { point, ray }))
            .collect();
        jobs.sort_by_key(|j| hash(j.point.wrapping_mul(7919) ^ j.ray));
        let once = jobs.len();
        if rays == 32 {
            while jobs.len() <= JOB_CHUNK {
                jobs.extend_from_within(..once);
            }
        }
        let scores = ao
            .cast_rays(&ctx, &gpu_scene, &ids, &pts, &nrm, &jobs, &params)
            .unwrap();
        assert_eq!(scores.len(), jobs.len());
        let mut per_point = vec![vec![f32::NAN; rays as usize]; n];
        for (j, &s) in jobs.iter().zip(&scores).take(once) {
            per_point[j.point as usize][j.ray as usize] = s;
        }
        // A ray cast again, in another dispatch, scores the same.
        for (j, &s) in jobs.iter().zip(&scores).skip(once) {
            let first = per_point[j.point as usize][j.ray as usize];
            assert_eq!(s.to_bits(), first.to_bits(), "{j:?}");
        }
        // Summed as the AO pass sums them: its AO, bit for bit.
        let whole = ao
            .trace_ids(&ctx, &gpu_scene, &ids, &pts, &nrm, &params)
            .unwrap();
        let mut agree = 0usize;
        for (i, scores) in per_point.iter().enumerate() {
            assert_eq!(
                ao_of_scores(scores).to_bits(),
                whole.ao[i].to_bits(),
                "{rays} rays, {estimator:?}: point {i}"
            );
            // The CPU's rays are the same rays.
            let cpu = PointRays::new(ids[i], pts[i], nrm[i], &params);
            for (k, &s) in scores.iter().enumerate() {
                let c = cpu.as_ref().map_or(1.0, |r| r.score(&cpu_tracer, k as u32));
                agree += usize::from((c - s).abs() <= 1e-3);
            }
            if !pts[i].is_finite() {
                assert!(scores.iter().all(|&s| s == 1.0), "point {i}");
            }
        }
        let share = agree as f64 / (n as f64 * rays as f64);
        eprintln!(
            "{rays} rays, {estimator:?}: {:.4}% of rays as on the CPU",
            share * 100.0
        );
        assert!(share >= 0.999, "{rays} rays, {estimator:?}: {share}");
    }
    let params = AoParams::default();
    // Nothing asked, nothing cast.
    let none = ao.cast_rays(&ctx, &gpu_scene, &ids, &pts, &nrm, &[], &params);
    assert_eq!(none.unwrap(), Vec::<f32>::new());
    // A job past the batch or the point's rays is an error naming it.
    for bad in [
        RayJob {
            point: n as u32,
            ray: 0,
        },
        RayJob {
            point: 0,
            ray: params.rays,
        },
    ] {
        let jobs = [RayJob { point: 1, ray: 1 }, bad];
        let e = ao
            .cast_rays(&ctx, &gpu_scene, &ids, &pts, &nrm, &jobs, &params)
            .unwrap_err();
        assert!(matches!(e, GpuError::Input(_)), "{e}");
        assert!(e.to_string().contains("ray job 1"), "{e}");
    }
    // Points, normals and ids that do not line up.
    let e = ao
        .cast_rays(&ctx, &gpu_scene, &ids[1..], &pts, &nrm, &[], &params)
        .unwrap_err();
    assert!(matches!(e, GpuError::Input(_)), "{e}");
}

#[test]
fn rays_pass_through_alpha_mask_holes_on_the_gpu_as_on_the_cpu() {
    let Some(ctx) = context() else { return };
    let scene = default_scene();
    // Points on the floor beside the trellis (x = 11.4, z in 4..6, 2 m
    // tall), facing it: many of their rays cross its holes.
    let (mut ids, mut pts, mut nrm) = (Vec::new(), Vec::new(), Vec::new());
    for k in 0..400u32 {
        let (a, b) = ((k % 20) as f32 / 20.0, (k / 20) as f32 / 20.0);
        ids.push(k);
        pts.push(Vec3::new(10.9 + 0.45 * a, 0.0, 4.0 + 2.0 * b));
        nrm.push(Vec3::Y);
    }
    let params = AoParams {
        rays: 64,
        ..AoParams::default()
    };
    let cpu = PosedScene::new(&scene, 0.0)
        .unwrap()
        .tracer()
        .trace_ids(&ids, &pts, &nrm, &params)
        .unwrap();
    let gpu_scene = GpuScene::new(&ctx, &scene).unwrap();
    let ao = GpuAo::new(&ctx).unwrap();
    let gpu = ao
        .trace_ids(&ctx, &gpu_scene, &ids, &pts, &nrm, &params)
        .unwrap();
    let (share, worst) = agreement(&cpu.ao, &gpu.ao);
    assert!(
        share >= 0.99,
        "{:.2}% of points within 1/255 (worst {worst})",
        share * 100.0
    );
    // A solid trellis occludes more: the holes matter to these points.
    let solid = solid_default_scene();
    let solid_gpu = ao
        .trace_ids(
            &ctx,
            &GpuScene::new(&ctx, &solid).unwrap(),
            &ids,
            &pts,
            &nrm,
            &params,
        )
        .unwrap();
    let mean = |v: &[f32]| v.iter().sum::<f32>() / v.len() as f32;
    assert!(
        mean(&solid_gpu.ao) < mean(&gpu.ao) - 0.01,
        "solid {} against masked {}",
        mean(&solid_gpu.ao),
        mean(&gpu.ao)
    );
}

#[test]
fn a_deforming_mesh_updates_its_blas() {
    let Some(ctx) = context() else { return };
    let scene = cesium_man_scene();
    let mut p = pipeline(&scene, 64.0, default_rays());
    let mut gpu_scene = GpuScene::new(&ctx, &scene).unwrap();
    let ao = GpuAo::new(&ctx).unwrap();
    let params = AoParams {
        rays: 32,
        ..AoParams::default()
    };
    let (ids, pts0, nrm0) = world_points(&p);
    let at0 = ao
        .trace_ids(&ctx, &gpu_scene, &ids, &pts0, &nrm0, &params)
        .unwrap();
    // Half a second on, the figure has moved its limbs.
    let t = 0.5;
    p.step(t).unwrap();
    gpu_scene.pose(&ctx, &scene, t).unwrap();
    let (ids, pts, nrm) = world_points(&p);
    let cpu = PosedScene::new(&scene, t)
        .unwrap()
        .tracer()
        .trace_ids(&ids, &pts, &nrm, &params)
        .unwrap();
    let gpu = ao
        .trace_ids(&ctx, &gpu_scene, &ids, &pts, &nrm, &params)
        .unwrap();
    let (share, worst) = agreement(&cpu.ao, &gpu.ao);
    assert!(
        share >= 0.999,
        "after the pose: {:.3}% within 1/255 (worst {worst})",
        share * 100.0
    );
    // Negative control: structures left at time 0 do not give this.
    let stale_scene = GpuScene::new(&ctx, &scene).unwrap();
    let stale = ao
        .trace_ids(&ctx, &stale_scene, &ids, &pts, &nrm, &params)
        .unwrap();
    let (stale_share, _) = agreement(&cpu.ao, &stale.ao);
    assert!(
        stale_share < 0.999,
        "a BLAS left at time 0 agrees with the CPU at time {t} on {:.3}% of points",
        stale_share * 100.0
    );
    let moved = pts0
        .iter()
        .zip(&pts)
        .filter(|(a, b)| (**a - **b).length() > 1e-3)
        .count();
    assert!(moved > 20, "{moved} points moved");
    assert_eq!(at0.ao.len(), gpu.ao.len());
}

#[test]
fn unsupported_scenes_and_bad_inputs_are_errors() {
    let Some(ctx) = context() else { return };
    let scene = default_scene();
    let gs = GpuScene::new(&ctx, &scene).unwrap();
    let ao = GpuAo::new(&ctx).unwrap();
    let e = ao
        .trace_ids(&ctx, &gs, &[0], &[Vec3::ZERO], &[], &AoParams::default())
        .unwrap_err();
    assert!(matches!(e, GpuError::Input(_)), "{e}");
    let e = ao
        .trace_ids(
            &ctx,
            &gs,
            &[0],
            &[Vec3::ZERO],
            &[Vec3::Y],
            &AoParams {
                radius: -1.0,
                ..AoParams::default()
            },
        )
        .unwrap_err();
    assert!(matches!(e, GpuError::Scene(_)), "{e}");
    // Non-finite points are open, as on the CPU; no points, no work.
    let r = ao
        .trace_ids(
            &ctx,
            &gs,
            &[0, 1],
            &[Vec3::NAN, Vec3::new(0.0, f32::INFINITY, 0.0)],
            &[Vec3::Y, Vec3::Y],
            &AoParams::default(),
        )
        .unwrap();
    assert_eq!(r.ao, vec![1.0, 1.0]);
    let r = ao
        .trace_ids(&ctx, &gs, &[], &[], &[], &AoParams::default())
        .unwrap();
    assert!(r.ao.is_empty());
}

#[test]
fn the_missing_driver_error_says_what_to_install() {
    let e = GpuError::NoAdapter {
        details: "none".into(),
    };
    let s = e.to_string();
    assert!(s.contains("no usable GPU adapter"), "{s}");
    assert!(
        s.contains("lavapipe") && s.contains("mesa-vulkan-drivers"),
        "{s}"
    );
    let e = GpuError::NoRayQuery {
        adapter: "x".into(),
        driver: "y".into(),
    };
    assert!(e.to_string().contains("no Vulkan adapter with ray queries"));
}

#[test]
fn a_pipeline_on_the_gpu_streams_the_same_frames_as_on_the_cpu() {
    let Some(_ctx) = context() else { return };
    // The default scene (the box slides, the walker's skin deforms) and a
    // cube whose morph weights an animation drives.
    let cube = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../psao-scene/tests/data/AnimatedMorphCube.glb");
    let morph = stage(load_gltf(&cube).unwrap()).unwrap();
    // Settling (the AO of every traced point read back and compared on
    // the host) and a lead, on the default scene.
    // And a ray budget per step (issue 20): both backends then plan full
    // traces (no kept ray scores, which only the CPU tracer has and which
    // make its points cheaper under a budget), so they take the same
    // budget decisions and must send the same frames.
    // With kept ray scores too (ray reuse and early decisions): the GPU
    // backend with single rays casts the rays each point asks for
    // (`AoBackend::cast_rays`), so
    // both take the same decisions from the same scores, cast the same
    // rays and send the same frames.
    let budget = RayBudget::Rays(800);
    let (plain, kept) = (false, true);
    for (name, scene, settle_steps, lead, budget, scores) in [
        (
            "default",
            default_scene(),
            0,
            0.0,
            RayBudget::Unlimited,
            plain,
        ),
        (
            "default, settling, lead",
            default_scene(),
            1,
            1.0 / 30.0,
            RayBudget::Unlimited,
            plain,
        ),
        (
            "morph cube",
            morph.clone(),
            0,
            0.0,
            RayBudget::Unlimited,
            plain,
        ),
        ("default, a budget", default_scene(), 0, 0.0, budget, plain),
        (
            "default, a budget, kept scores",
            default_scene(),
            0,
            0.0,
            budget,
            kept,
        ),
        (
            "default, kept scores",
            default_scene(),
            0,
            0.0,
            RayBudget::Unlimited,
            kept,
        ),
        ("morph cube, kept scores", morph, 0, 0.0, budget, kept),
    ] {
        let config = PipelineConfig {
            density: 16.0,
            ao: AoParams {
                rays: 16,
                ..AoParams::default()
            },
            settle_steps,
            lead,
            budget,
            ray_reuse: budget == RayBudget::Unlimited || scores,
            early: scores.then(EarlyDecisions::default),
            // Points known open cast no ray on the CPU alone: off, so
            // that the rays cast compare.
            skip_open: !scores,
            ..PipelineConfig::default()
        };
        let mut cpu = Pipeline::new(scene.clone(), config.clone()).unwrap();
        let backend = GpuBackend::new(&scene).unwrap().with_single_rays(scores);
        let mut gpu = Pipeline::with_backend(scene, config, Box::new(backend)).unwrap();
        assert!(
            gpu.backend_name().starts_with("gpu"),
            "{}",
            gpu.backend_name()
        );
        assert_eq!(cpu.keyframe().unwrap().bytes, gpu.keyframe().unwrap().bytes);
        // The same points are traced and the same dirty sets sent.
        let (mut traced, mut deformed, mut settled, mut waited) = (0, 0, 0, 0);
        let (mut early, mut rays_kept) = (0, 0);
        for _ in 0..20 {
            let (a, ra) = cpu.step(1.0 / 30.0).unwrap();
            let (b, rb) = gpu.step(1.0 / 30.0).unwrap();
            assert_eq!(ra.traced, rb.traced, "{name}");
            if scores {
                assert_eq!(ra.rays, rb.rays, "{name}: rays cast");
                assert_eq!(ra.rays_kept, rb.rays_kept, "{name}: rays kept");
                assert_eq!(ra.early, rb.early, "{name}: early stops");
                early += rb.early;
                rays_kept += rb.rays_kept;
            }
            assert_eq!(ra.waiting, rb.waiting, "{name}: points left waiting");
            waited += rb.waiting;
            assert_eq!(ra.updated, rb.updated, "{name}: dirty sets differ");
            assert_eq!(ra.settled, rb.settled, "{name}");
            settled += rb.settled;
            assert_eq!(a.map(|f| f.bytes), b.map(|f| f.bytes), "{name}");
            traced += rb.traced;
            deformed += rb.deformed;
        }
        assert!(traced > 0 && deformed > 0, "{name}: {traced} {deformed}");
        // Kept scores at work on the GPU: rays kept, points stopped early.
        assert_eq!(
            (rays_kept > 0, early > 0),
            (scores, scores),
            "{name}: {rays_kept} rays kept, {early} early stops"
        );
        assert_eq!(settled > 0, settle_steps > 0, "{name}: {settled} settled");
        // The budget bound: points waited for a later step.
        assert_eq!(
            waited > 0,
            budget != RayBudget::Unlimited,
            "{name}: {waited} waited"
        );
    }
}

/// What clients of `p` hold for each of its points (cells numbered across
/// instances, as the pipeline numbers them), in the order of `points_of`.
fn held(p: &Pipeline) -> Vec<psao_codec::SentPoint> {
    let mut sent = Vec::new();
    let mut cell_base = 0;
    for i in 0..p.instance_count() {
        let table = p.table(i).unwrap();
        let (pos, n) = p.stored_points(i).unwrap();
        for k in 0..pos.len() {
            let mut s = table.sent(k as u32, pos[k], n[k]);
            s.cell = s.cell.saturating_add(cell_base);
            sent.push(s);
        }
        cell_base += table.def().cell_pool;
    }
    sent
}

#[test]
fn the_gpu_compares_with_what_clients_hold_and_reads_back_only_changes() {
    let Some(ctx) = context() else { return };
    let scene = default_scene();
    let p = pipeline(&scene, 16.0, default_rays());
    let (ids, pts, nrm) = world_points(&p);
    let mut sent = held(&p);
    // Exercise every threshold: some points moved by 6.4 quanta, some
    // turned around, some not held at all, some held 3 steps short of
    // open (sent where their AO comes out open); the rest differ in AO
    // only (another seed, 16 rays: steps of 16/255).
    for (k, s) in sent.iter_mut().enumerate() {
        match k % 17 {
            3 => s.frac.x = (s.frac.x + 0.2) % 1.0,
            5 => s.normal = -s.normal,
            7 => *s = psao_codec::SentPoint::not_held(s.normal),
            11 if s.word.is_allocated() => s.word = s.word.with_ao(252),
            _ => {}
        }
    }
    let params = AoParams {
        rays: 16,
        seed: 0x5eed_0002,
        ..AoParams::default()
    };
    let th = psao_codec::Thresholds::default();
    let gpu_scene = GpuScene::new(&ctx, &scene).unwrap();
    let ao = GpuAo::new(&ctx).unwrap();
    // The same comparison on the host, on the GPU's own AO: identical.
    let batch = Batch {
        ids: &ids,
        pts: &pts,
        nrm: &nrm,
        sent: &sent,
    };
    let (on_gpu, on_host) = both_ways(&ctx, &ao, &gpu_scene, &batch, &params, &th);
    assert_eq!(on_gpu.changed, on_host.changed);
    assert_eq!(on_gpu.cells, on_host.cells);
    assert_eq!(on_gpu.rays, on_host.rays);
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&on_gpu.ao), bits(&on_host.ao));
    // Not everything and not nothing: the comparison decided.
    let n = pts.len();
    assert!(
        on_gpu.changed.len() > n / 10 && on_gpu.changed.len() < n,
        "{} of {n} changed",
        on_gpu.changed.len()
    );
    for (k, _) in sent
        .iter()
        .enumerate()
        .filter(|(k, _)| [3, 5, 7].contains(&(k % 17)))
    {
        assert!(
            on_gpu.changed.binary_search(&(k as u32)).is_ok(),
            "point {k}"
        );
    }
    // Some points held 3 steps short of open came out open, and were
    // sent below the threshold.
    let opened = on_gpu
        .changed
        .iter()
        .zip(&on_gpu.ao)
        .filter(|&(&k, &ao)| k % 17 == 11 && psao_codec::wire::point::quantize_ao(ao) == 255)
        .count();
    assert!(opened > 0, "no point held short of open came out open");
    // Against the CPU backend's AO: the same decisions but for points
    // whose AO differs in the last bits right at a threshold.
    let cpu = PosedScene::new(&scene, 0.0)
        .unwrap()
        .tracer()
        .trace_ids(&ids, &pts, &nrm, &params)
        .unwrap();
    let on_cpu = ChangedPoints::compare(&cpu, &sent, &th).unwrap();
    let differ = on_cpu
        .changed
        .iter()
        .filter(|k| on_gpu.changed.binary_search(k).is_err())
        .count()
        + on_gpu
            .changed
            .iter()
            .filter(|k| on_cpu.changed.binary_search(k).is_err())
            .count();
    eprintln!(
        "{n} points: {} changed on the GPU, {} on the CPU, {differ} decisions differ",
        on_gpu.changed.len(),
        on_cpu.changed.len()
    );
    assert!(differ * 1000 <= n, "{differ} of {n} decisions differ");
    // Without the made-up records, setting the changed points dirties at
    // least the cells listed.
    let on_gpu = ao
        .trace_changed(&ctx, &gpu_scene, &ids, &pts, &nrm, &held(&p), &params, &th)
        .unwrap();
    let mut tables: Vec<psao_codec::GridTable> = (0..p.instance_count())
        .map(|i| p.table(i).unwrap().clone())
        .collect();
    let mut owners = Vec::new();
    let mut cell_base = 0;
    let mut bases = Vec::new();
    for (i, t) in tables.iter().enumerate() {
        bases.push(cell_base);
        cell_base += t.def().cell_pool;
        owners.extend((0..p.current_points(i).unwrap().0.len()).map(|k| (i, k)));
    }
    for t in &mut tables {
        t.take_dirty();
    }
    for (&at, &v) in on_gpu.changed.iter().zip(&on_gpu.ao) {
        let (i, k) = owners[at as usize];
        let (pos, n) = p.stored_points(i).unwrap();
        tables[i].set_point(k as u32, pos[k], n[k], v).unwrap();
    }
    let dirty: Vec<u32> = tables
        .iter_mut()
        .enumerate()
        .flat_map(|(i, t)| {
            let base = bases[i];
            t.take_dirty().cells.into_iter().map(move |c| base + c.cell)
        })
        .collect();
    assert!(!on_gpu.cells.is_empty());
    for c in &on_gpu.cells {
        assert!(dirty.contains(c), "listed cell {c} is not dirty");
    }
}

/// Points to trace and what their clients hold.
struct Batch<'a> {
    ids: &'a [u32],
    pts: &'a [Vec3],
    nrm: &'a [Vec3],
    sent: &'a [psao_codec::SentPoint],
}

/// The changed points of `b` compared on the GPU, and on the host from the
/// GPU's own AO.
fn both_ways(
    ctx: &GpuContext,
    ao: &GpuAo,
    scene: &GpuScene,
    b: &Batch<'_>,
    params: &AoParams,
    th: &psao_codec::Thresholds,
) -> (ChangedPoints, ChangedPoints) {
    let on_gpu = ao
        .trace_changed(ctx, scene, b.ids, b.pts, b.nrm, b.sent, params, th)
        .unwrap();
    let traced = ao
        .trace_ids(ctx, scene, b.ids, b.pts, b.nrm, params)
        .unwrap();
    (on_gpu, ChangedPoints::compare(&traced, b.sent, th).unwrap())
}

#[test]
fn the_changed_point_lists_span_dispatches_and_list_each_cell_once() {
    let Some(ctx) = context() else { return };
    let scene = solid_default_scene();
    let p = pipeline(&scene, 16.0, default_rays());
    let (ids, pts, nrm) = world_points(&p);
    let sent = held(&p);
    // More points than one dispatch takes (2^18): the batch repeated,
    // every copy held with AO 0 so that every copy changes.
    let copies = (1usize << 18) / pts.len() + 2;
    let rep = |v: &[Vec3]| v.repeat(copies);
    let (pts, nrm) = (rep(&pts), rep(&nrm));
    let ids: Vec<u32> = (0..copies as u32)
        .flat_map(|c| ids.iter().map(move |&i| i + c * 1_000_000))
        .collect();
    let sent: Vec<_> = sent
        .repeat(copies)
        .into_iter()
        .map(|mut s| {
            if s.word.is_allocated() {
                s.word = s.word.with_ao(0);
            }
            s
        })
        .collect();
    assert!(pts.len() > 1 << 18);
    let params = AoParams {
        rays: 1,
        estimator: Estimator::LaineKarras,
        ..AoParams::default()
    };
    let th = psao_codec::Thresholds {
        ao_steps: 0,
        ..Default::default()
    };
    let gpu_scene = GpuScene::new(&ctx, &scene).unwrap();
    let ao = GpuAo::new(&ctx).unwrap();
    let batch = Batch {
        ids: &ids,
        pts: &pts,
        nrm: &nrm,
        sent: &sent,
    };
    let (on_gpu, on_host) = both_ways(&ctx, &ao, &gpu_scene, &batch, &params, &th);
    assert_eq!(on_gpu, on_host);
    let mut once = on_gpu.cells.clone();
    once.dedup();
    assert_eq!(once, on_gpu.cells, "a cell listed twice");
    assert!(!on_gpu.cells.is_empty());
    assert!(
        on_gpu.changed.len() > pts.len() / 4,
        "{}",
        on_gpu.changed.len()
    );
}

#[test]
fn the_triangle_order_changes_no_ao() {
    let Some(ctx) = context() else { return };
    // The whole default scene, alpha-masked trellis included (its mask is
    // looked up by primitive index, which the order changes).
    let scene = default_scene();
    let p = pipeline(&scene, 16.0, default_rays());
    let (ids, pts, nrm) = world_points(&p);
    let ao = GpuAo::new(&ctx).unwrap();
    let params = AoParams {
        rays: 16,
        ..AoParams::default()
    };
    let trace = |order| {
        let s = GpuScene::with_order(&ctx, &scene, order).unwrap();
        ao.trace_ids(&ctx, &s, &ids, &pts, &nrm, &params)
            .unwrap()
            .ao
    };
    let given = trace(TriangleOrder::AsGiven);
    let median = trace(TriangleOrder::MedianSplit);
    let same = given
        .iter()
        .zip(&median)
        .filter(|(a, b)| (*a - *b).abs() <= 1e-6)
        .count();
    eprintln!("{same} of {} points equal", given.len());
    assert!(
        same * 1000 >= given.len() * 999,
        "{same} of {}",
        given.len()
    );
    let (share, worst) = agreement(&given, &median);
    assert_eq!(share, 1.0, "worst {worst}");
}

#[test]
fn changed_points_of_an_empty_scene_or_batch_are_decided_on_the_host() {
    let Some(ctx) = context() else { return };
    let ao = GpuAo::new(&ctx).unwrap();
    let th = psao_codec::Thresholds::default();
    let params = AoParams::default();
    // No triangles: no TLAS, so everything is open and compared on the
    // host; a held word with AO 0 changes, one with AO 255 does not.
    let empty = GpuScene::new(&ctx, &Scene::default()).unwrap();
    let word = |ao: u8| psao_codec::PointWord::encode(Vec3::splat(0.5), Vec3::Y, 0.0).with_ao(ao);
    let sent = [0u8, 255].map(|a| psao_codec::SentPoint {
        word: word(a),
        frac: word(a).frac(),
        normal: word(a).normal(),
        cell: 7,
    });
    let pts = [Vec3::ZERO, Vec3::X];
    let nrm = [Vec3::Y, Vec3::Y];
    let out = ao
        .trace_changed(&ctx, &empty, &[0, 1], &pts, &nrm, &sent, &params, &th)
        .unwrap();
    assert_eq!(out.changed, vec![0]);
    assert_eq!(out.ao, vec![1.0]);
    assert_eq!(out.cells, vec![7]);
    // Nothing to trace, and mismatched inputs.
    let scene = GpuScene::new(&ctx, &default_scene()).unwrap();
    let none = ao
        .trace_changed(&ctx, &scene, &[], &[], &[], &[], &params, &th)
        .unwrap();
    assert_eq!(none, ChangedPoints::default());
    assert!(matches!(
        ao.trace_changed(&ctx, &scene, &[0, 1], &pts, &nrm, &sent[..1], &params, &th),
        Err(GpuError::Input(_))
    ));
}
