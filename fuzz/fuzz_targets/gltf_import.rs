//! Any bytes as a glTF document: never panics; a model that loads is valid
//! (its scene passes validation and its triangles are finite).
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(scene) = psao_scene::load_gltf_slice(data, "fuzz", None) {
        let tris = scene.world_triangles().expect("a loaded scene validates");
        assert!(tris.iter().flatten().all(|p| p.is_finite()));
    }
});
