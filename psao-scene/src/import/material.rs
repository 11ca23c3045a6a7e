//! Materials: a `MASK` material becomes an [`AlphaMask`] from its cutoff,
//! the base colour factor and `COLOR_0`; an alpha mask read from a texture
//! is refused.

use gltf::accessor::Dimensions;
use gltf::mesh::Semantic;

use super::gltf_error;
use crate::error::SceneError;
use crate::model::alpha::AlphaMask;

/// The alpha mask of `prim`'s material (`None` unless its alpha mode is
/// `MASK`): its cutoff, the base colour factor's alpha and, when the
/// primitive has a VEC4 `COLOR_0`, each vertex's alpha, read with
/// `attribute` (one of the primitive's vertex attributes, checked against
/// its vertex count).
pub(super) fn alpha_mask(
    prim: &gltf::Primitive<'_>,
    name: &str,
    attribute: &dyn Fn(Semantic, Dimensions) -> Result<Option<Vec<f32>>, SceneError>,
) -> Result<Option<AlphaMask>, SceneError> {
    let material = prim.material();
    let alpha = match material.alpha_mode() {
        gltf::material::AlphaMode::Mask => {
            let pbr = material.pbr_metallic_roughness();
            if let Some(t) = pbr.base_color_texture() {
                return Err(gltf_error(
                    name,
                    &format!(
                        "material {}",
                        material.index().map_or("default".into(), |i| i.to_string())
                    ),
                    format!(
                        "alpha mask from texture {} is not supported (factor and COLOR_0 masks are)",
                        t.texture().index()
                    ),
                ));
            }
            let vertex_alpha = match prim.get(&Semantic::Colors(0)) {
                Some(a) if a.dimensions() == Dimensions::Vec4 => {
                    attribute(Semantic::Colors(0), Dimensions::Vec4)?
                        .unwrap_or_default()
                        .chunks_exact(4)
                        .map(|c| c[3])
                        .collect()
                }
                _ => Vec::new(),
            };
            Some(AlphaMask {
                cutoff: material.alpha_cutoff().unwrap_or(0.5),
                factor: pbr.base_color_factor()[3],
                vertex_alpha,
                texture: None,
            })
        }
        _ => None,
    };
    Ok(alpha)
}
