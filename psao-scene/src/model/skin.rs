//! Linear blend skinning: a skin's joints are nodes; each vertex follows a
//! weighted blend of up to four joint transforms.
//!
//! Skinning works in the instance's local space (where a posed grid lives;
//! a bind-space grid, point format 1, stays in the mesh's own space): the
//! joint matrix of joint `j` is `inverse(instance world) * world(j) *
//! inverse_bind(j)`, so a skinned instance that also moves as a whole sends
//! its rigid part as a transform and only the deformation as point updates.

use glam::{Affine3A, Vec3};

/// The joints of a skin.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Skin {
    /// Name (for messages).
    pub name: String,
    /// The joint nodes (indices into [`Scene::nodes`](crate::Scene::nodes)).
    pub joints: Vec<usize>,
    /// Per joint, the inverse of its world transform in the bind pose.
    pub inverse_bind: Vec<Affine3A>,
}

/// Per-vertex joint influences of a skinned mesh.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SkinWeights {
    /// Up to four joints per vertex (indices into [`Skin::joints`]).
    pub joints: Vec<[u16; 4]>,
    /// Their weights (not negative; a vertex whose weights sum to zero
    /// stays where it is).
    pub weights: Vec<[f32; 4]>,
}

impl Skin {
    /// Joint matrices (instance-local) for joint world transforms `nodes`
    /// and an instance whose world transform is `instance`, into `out`.
    pub fn joint_matrices(&self, nodes: &[Affine3A], instance: &Affine3A, out: &mut Vec<Affine3A>) {
        let to_local = instance.inverse();
        out.clear();
        out.extend(self.joints.iter().zip(&self.inverse_bind).map(|(&j, ibm)| {
            nodes
                .get(j)
                .map_or(Affine3A::IDENTITY, |w| to_local * *w * *ibm)
        }));
    }
}

impl SkinWeights {
    /// The blended transform of vertex `v` under `matrices`, or `None` when
    /// its weights sum to zero (it stays put). Joint indices past the
    /// matrices count as zero weight.
    pub fn blend(&self, v: usize, matrices: &[Affine3A]) -> Option<Affine3A> {
        let (j, w) = (self.joints.get(v)?, self.weights.get(v)?);
        let mut sum = 0.0;
        let mut m = [Vec3::ZERO; 4];
        for k in 0..4 {
            let Some(mat) = matrices.get(j[k] as usize) else {
                continue;
            };
            if w[k] <= 0.0 {
                continue;
            }
            sum += w[k];
            m[0] += mat.matrix3.x_axis.to_vec3() * w[k];
            m[1] += mat.matrix3.y_axis.to_vec3() * w[k];
            m[2] += mat.matrix3.z_axis.to_vec3() * w[k];
            m[3] += mat.translation.to_vec3() * w[k];
        }
        (sum > 0.0).then(|| {
            let s = 1.0 / sum;
            Affine3A::from_cols(
                (m[0] * s).into(),
                (m[1] * s).into(),
                (m[2] * s).into(),
                (m[3] * s).into(),
            )
        })
    }

    /// Skins `positions` and `normals` (bind pose) into `out_p`, `out_n`.
    /// Normals go through the inverse transpose and are renormalized.
    pub fn skin(
        &self,
        positions: &[Vec3],
        normals: &[Vec3],
        matrices: &[Affine3A],
        out_p: &mut Vec<Vec3>,
        out_n: &mut Vec<Vec3>,
    ) {
        out_p.clear();
        out_n.clear();
        for (v, (&p, &n)) in positions.iter().zip(normals).enumerate() {
            match self.blend(v, matrices) {
                Some(m) => {
                    out_p.push(m.transform_point3(p));
                    let nm = m.matrix3.inverse().transpose();
                    out_n.push((nm * n).normalize_or(n));
                }
                None => {
                    out_p.push(p);
                    out_n.push(n);
                }
            }
        }
    }
}
