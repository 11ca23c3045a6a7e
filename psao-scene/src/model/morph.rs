//! Morph targets (glTF 2.0 3.7.2.1): per-vertex position and normal
//! offsets blended by weights that an animation can drive. A mesh whose
//! weights never change has its targets applied once at import; one whose
//! weights are animated keeps them here and deforms like a skinned mesh,
//! before its skin (if any).

use glam::Vec3;

/// The morph targets of a mesh whose weights are animated. The mesh's own
/// positions and normals are the ones at [`rest_weights`](Self::rest_weights),
/// so a pose at other weights `w` adds `(w_k - rest_k) * delta_k` per target.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct MorphTargets {
    /// The weights the mesh's positions and normals were made with (the
    /// node's or mesh's default weights), one per target.
    pub rest_weights: Vec<f32>,
    /// Per target, a position offset per vertex, or empty when the target
    /// moves no position.
    pub positions: Vec<Vec<Vec3>>,
    /// Per target, a normal offset per vertex, or empty when the target
    /// turns no normal.
    pub normals: Vec<Vec<Vec3>>,
}

impl MorphTargets {
    /// Number of targets.
    pub fn len(&self) -> usize {
        self.rest_weights.len()
    }

    /// Whether there are no targets.
    pub fn is_empty(&self) -> bool {
        self.rest_weights.is_empty()
    }

    /// Checks there is one offset list (or none) per target, each with one
    /// finite offset per vertex, and finite rest weights. The reason names
    /// what was wrong.
    pub fn check(&self, vertices: usize) -> Result<(), String> {
        let n = self.len();
        if self.positions.len() != n || self.normals.len() != n {
            return Err(format!(
                "{} position and {} normal offset lists for {n} targets",
                self.positions.len(),
                self.normals.len()
            ));
        }
        if let Some(k) = self.rest_weights.iter().position(|w| !w.is_finite()) {
            return Err(format!("rest weight {k} is not finite"));
        }
        for (what, lists) in [("position", &self.positions), ("normal", &self.normals)] {
            for (k, d) in lists.iter().enumerate() {
                if !d.is_empty() && d.len() != vertices {
                    return Err(format!(
                        "target {k} has {} {what} offsets for {vertices} vertices",
                        d.len()
                    ));
                }
                if let Some(v) = d.iter().position(|x| !x.is_finite()) {
                    return Err(format!("target {k} {what} offset {v} is not finite"));
                }
            }
        }
        Ok(())
    }

    /// Positions and normals at `weights` (a missing weight is the rest
    /// weight) from the rest ones, into `out_p` and `out_n`; normals are
    /// renormalized (a normal that cancels out keeps its rest direction).
    /// The targets must be [`check`](Self::check)ed against the vertices.
    pub fn apply(
        &self,
        weights: &[f32],
        positions: &[Vec3],
        normals: &[Vec3],
        out_p: &mut Vec<Vec3>,
        out_n: &mut Vec<Vec3>,
    ) {
        out_p.clear();
        out_p.extend_from_slice(positions);
        out_n.clear();
        out_n.extend_from_slice(normals);
        let mut turned = false;
        for (k, rest) in self.rest_weights.iter().enumerate() {
            let dw = weights.get(k).copied().unwrap_or(*rest) - rest;
            if dw == 0.0 || !dw.is_finite() {
                continue;
            }
            for (p, d) in out_p.iter_mut().zip(&self.positions[k]) {
                *p += dw * *d;
            }
            if !self.normals[k].is_empty() {
                turned = true;
                for (n, d) in out_n.iter_mut().zip(&self.normals[k]) {
                    *n += dw * *d;
                }
            }
        }
        if turned {
            for (n, rest) in out_n.iter_mut().zip(normals) {
                *n = n.try_normalize().unwrap_or(*rest);
            }
        }
    }
}
