//! Any bytes as a glTF document: never panics; a model that loads is valid
//! (its scene passes validation and its triangles are finite), and its
//! animations, morphs and skins evaluate at any time without panicking.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(scene) = psao_scene::load_gltf_slice(data, "fuzz", None) {
        let tris = scene.world_triangles().expect("a loaded scene validates");
        assert!(tris.iter().flatten().all(|p| p.is_finite()));
        // Animation and skinning at any time never panic (a later pose may
        // be degenerate; the pipeline reports that as an error).
        // Whatever its durations, the scene's loop is a finite positive
        // time within the bound, or none.
        if let Some(p) = scene.loop_period(20.0) {
            assert!(p.is_finite() && p > 0.0 && p <= 20.0, "loop of {p} s");
        }
        for t in [0.0, 0.37, 1e3, -1.0] {
            let pose = scene.pose(t);
            for i in 0..scene.instances.len() {
                let _ = scene.deformed(i, &pose);
            }
        }
    }
});
