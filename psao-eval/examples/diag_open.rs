//! temporary diagnostic (not committed)
use psao_codec::{Decoder, Limits, WeightParams, weight};
use psao_eval::*;
use psao_scene::*;

fn main() {
    let scene = cesium_man_scene();
    let mut config = PipelineConfig::with_density_and_rays(2048.0, 32);
    config.ao.radius = 0.6;
    let params = config.ao;
    let mut p = Pipeline::new(scene.clone(), config).unwrap();
    let mut c = Decoder::new(Limits::default());
    c.receive(&p.keyframe().unwrap().bytes).unwrap();
    let path = scene.camera.clone().unwrap();
    let t = path.duration() * 0.25;
    if let (Some(fr), _) = p.step(t).unwrap() {
        c.receive(&fr.bytes).unwrap();
    }
    let view = View::new(path.at(t), 320, 180).unwrap();
    let posed = PosedScene::new(&scene, t).unwrap();
    let g = posed.gbuffer(&view);
    let tracer = posed.tracer();
    let refp = AoParams {
        rays: 128,
        ..params
    };
    let reference = ray_traced_ao(&tracer, &g, &refp).unwrap();
    let img = psao_image(c.mirror(), &g).unwrap();
    let m = c.mirror().instance(0).unwrap();
    let w = WeightParams::of(m.def());
    let (bpos, bnrm) = p.stored_points(0).unwrap();
    let (cpos, cnrm) = p.current_points(0).unwrap();
    let to_world = p.transform(0).unwrap();
    let table = p.table(0).unwrap();
    let mut n_bad = 0;
    let (mut sum_srv, mut sum_retrace, mut cnt) = (0.0, 0.0, 0);
    for k in 0..g.pixels() {
        if g.instance[k] != 0 || !(img.ao[k] >= 0.999 && reference[k] < 0.9) {
            continue;
        }
        n_bad += 1;
        let (x, n) = (g.bind_position[k], g.bind_normal[k]);
        for q in 0..bpos.len() {
            if weight(bpos[q], bnrm[q], x, n, &w) <= 0.0 {
                continue;
            }
            let psao_codec::Placement::Stored { cell, slot } = table.placement(q as u32) else {
                continue;
            };
            let srv = psao_codec::PointWord(table.cell(cell)[slot as usize]).ao();
            let wp = to_world.transform_point3(cpos[q]);
            let wn = to_world.transform_vector3(cnrm[q]).normalize();
            let re = tracer
                .trace_ids(&[q as u32], &[wp], &[wn], &refp)
                .unwrap()
                .ao[0];
            sum_srv += srv;
            sum_retrace += re;
            cnt += 1;
            if n_bad % 40 == 1 {
                println!(
                    "px {k}: ref {:.2} | point {q}: served {srv:.2}, retraced at its posed place {re:.2}, world dist {:.3}, pixel n.w {:.2}",
                    reference[k],
                    wp.distance(g.position[k]),
                    wn.dot(g.normal[k])
                );
            }
        }
    }
    println!(
        "bad pixels {n_bad}; contributing points {cnt}: mean served AO {:.3}, mean retraced AO {:.3}",
        sum_srv / cnt as f64 as f32,
        sum_retrace / cnt as f64 as f32
    );
}
