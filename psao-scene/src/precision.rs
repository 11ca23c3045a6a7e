//! Numerical limits: where f32 coordinates are too coarse for AO
//! ([`check_precision`]).

use glam::{Affine3A, Mat3A, Vec3};

use crate::error::SceneError;
use crate::model::mesh::transformed_bounds;

/// Largest f32 spacing at a world coordinate, as a fraction of the AO
/// radius R. Rays start 4 to 8 spacings off their surface
/// ([`ray_offset`](crate::ray_offset)), so this keeps that offset below
/// R / 8. Measured on the room of `tests/stability.rs`: its reference
/// image moved 0.017 (RMSE) from the unmoved room's at a spacing of R / 77
/// (1e5 from the origin), 0.018 at R / 38 (2e5) and 0.044 at R / 19 (5e5);
/// R / 64 accepts 1e5 and leaves a margin of 1.7 below the last good case.
pub const MAX_ULP_PER_AO_RADIUS: f32 = 1.0 / 64.0;

/// Largest f32 spacing of a point's position (in the instance's local
/// space), as a fraction of the point spacing r. Measured with 16384
/// points per m^2 (r = 0.012): the PSAO image stayed within its error
/// bound at a spacing of 0.66 r (RMSE 0.028 against 0.035) and left it at
/// 1.3 r (0.036); r / 2 leaves a margin below the good case (and so
/// refuses it).
pub const MAX_ULP_PER_POINT_SPACING: f32 = 0.5;

/// The spacing of f32 values at `x`: the distance from `|x|` to the next
/// larger f32 (infinite for the largest finite f32 and beyond, NaN for
/// NaN).
pub fn f32_spacing(x: f32) -> f32 {
    let a = x.abs();
    if !a.is_finite() {
        return a + f32::INFINITY;
    }
    f32::from_bits(a.to_bits() + 1) - a
}

/// The largest singular value of `m` (its spectral norm), from the largest
/// eigenvalue of `m^T m` in closed form (f64).
fn spectral_norm(m: &Mat3A) -> f64 {
    let c = [m.x_axis, m.y_axis, m.z_axis].map(|v| [v.x as f64, v.y as f64, v.z as f64]);
    let dot = |i: usize, j: usize| (0..3).map(|k| c[i][k] * c[j][k]).sum::<f64>();
    let a = [
        [dot(0, 0), dot(0, 1), dot(0, 2)],
        [dot(1, 0), dot(1, 1), dot(1, 2)],
        [dot(2, 0), dot(2, 1), dot(2, 2)],
    ];
    let q = (a[0][0] + a[1][1] + a[2][2]) / 3.0;
    let p1 = a[0][1] * a[0][1] + a[0][2] * a[0][2] + a[1][2] * a[1][2];
    let p2 = (0..3).map(|i| (a[i][i] - q) * (a[i][i] - q)).sum::<f64>() + 2.0 * p1;
    if p2 <= 0.0 {
        return q.max(0.0).sqrt();
    }
    let p = (p2 / 6.0).sqrt();
    let b = |i: usize, j: usize| (a[i][j] - if i == j { q } else { 0.0 }) / p;
    let det = b(0, 0) * (b(1, 1) * b(2, 2) - b(1, 2) * b(2, 1))
        - b(0, 1) * (b(1, 0) * b(2, 2) - b(1, 2) * b(2, 0))
        + b(0, 2) * (b(1, 0) * b(2, 1) - b(1, 1) * b(2, 0));
    let phi = (det / 2.0).clamp(-1.0, 1.0).acos() / 3.0;
    (q + 2.0 * p * phi.cos()).max(0.0).sqrt()
}

/// Checks that f32 places instance `instance` finely enough for AO:
/// `local_bounds` are its local bounds (for a skinned mesh, over its bind
/// pose and the poses it is traced in), `to_world` its transform, `point_spacing` the
/// interpolation radius r of its points (0 when it has none: then only the
/// AO radius rule applies) and `ao_radius` the AO radius R.
///
/// The coordinate checked is the largest absolute coordinate of the bounds'
/// corners, in world space (under `to_world`) and in local space. The
/// error, [`SceneError::Precision`], names the instance, that coordinate,
/// the f32 spacing there, the limit it passed and the rule.
/// [`Pipeline::new`](crate::Pipeline::new) checks every instance in its
/// pose at time 0 and [`Pipeline::place_instance`](crate::Pipeline::place_instance)
/// every placement; an animation that later carries an instance farther
/// out is not refused (it loses accuracy).
///
/// Every position is an f32, in two spaces: instance-local (mesh vertices,
/// points, the grid, the client's reconstruction) and world (AO rays, the
/// G-buffer). The spacing of f32 values (one ulp) grows with the
/// coordinate: about `|x| / 2^23`, 0.0078 at 1e5 and 1 at 1e7. AO needs
/// that spacing small against two lengths:
///
/// - the AO radius R, in world space: a ray starts
///   [`ray_offset`](crate::ray_offset) off its surface, which grows with the
///   coordinate (4 to 8 ulp) to stay above rounding; an offset that is a
///   large part of R misses nearby occluders. Rule:
///   `ulp(world) <= R *` [`MAX_ULP_PER_AO_RADIUS`].
/// - the point spacing r (the interpolation radius,
///   [`PointSet::radius`](crate::PointSet::radius)), in local space: the
///   client weighs points by their distance to the pixel's surface point
///   and rejects those off its tangent plane, so positions must be finer
///   than r. Rules: `ulp(local) <= r *` [`MAX_ULP_PER_POINT_SPACING`] and,
///   for world positions the client maps into local space,
///   `ulp(world) * |M^-1| <= r *` [`MAX_ULP_PER_POINT_SPACING`] (M the
///   instance transform's linear part, `|.|` its spectral norm).
///
/// The bounds come from `tests/stability.rs` (a floor, a wall and a box a
/// few metres across, R = 0.6, 128 points per m^2): moved 1e5 from the
/// origin (spacing R / 77), the PSAO image's RMSE against its reference
/// rose from 0.023 to 0.027 and the reference moved 0.017 from the unmoved
/// one; at 5e5 (R / 19) the reference moved 0.044; at 1e7 (spacing 1,
/// above R) rays started 4.8 off their surfaces, beyond R, and every image
/// came out uniformly open. See [`MAX_ULP_PER_AO_RADIUS`] and
/// [`MAX_ULP_PER_POINT_SPACING`] for the choice of each bound; both accept
/// that room at 1e5 and refuse it at 1e7.
pub fn check_precision(
    instance: usize,
    to_world: &Affine3A,
    local_bounds: (Vec3, Vec3),
    point_spacing: f32,
    ao_radius: f32,
) -> Result<(), SceneError> {
    let largest = |(lo, hi): (Vec3, Vec3)| lo.abs().max(hi.abs()).max_element();
    let world = largest(transformed_bounds(to_world, local_bounds));
    let local = largest(local_bounds);
    let refuse = |coordinate: f32, spacing: f32, limit: f32, reason: String| {
        Err(SceneError::Precision {
            instance,
            coordinate,
            spacing,
            limit,
            reason,
        })
    };
    let (ulp_world, limit) = (f32_spacing(world), ao_radius * MAX_ULP_PER_AO_RADIUS);
    // NaN is never within a limit.
    let within = |x: f32, limit: f32| x <= limit;
    if !within(ulp_world, limit) {
        return refuse(
            world,
            ulp_world,
            limit,
            format!(
                "world space: above 1/64 of the AO radius {ao_radius}, so AO rays would start \
                 too far off their surfaces; move the scene nearer the origin"
            ),
        );
    }
    if point_spacing > 0.0 {
        let limit = point_spacing * MAX_ULP_PER_POINT_SPACING;
        let ulp_local = f32_spacing(local);
        if !within(ulp_local, limit) {
            return refuse(
                local,
                ulp_local,
                limit,
                format!(
                    "local space: above half the point spacing {point_spacing}; \
                     move the mesh's vertices nearer its origin"
                ),
            );
        }
        let stretch = spectral_norm(&to_world.matrix3.inverse()) as f32;
        let seen = ulp_world * stretch;
        if !within(seen, limit) {
            return refuse(
                world,
                seen,
                limit,
                format!(
                    "world spacing {ulp_world} seen in local units (x {stretch}, the inverse \
                     transform's largest stretch): above half the point spacing {point_spacing}; \
                     move the scene nearer the origin"
                ),
            );
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Quat;

    #[test]
    fn spacing_of_f32_values() {
        assert_eq!(f32_spacing(1.0), f32::EPSILON);
        assert_eq!(f32_spacing(-1e5), 1.0 / 128.0);
        assert_eq!(f32_spacing(1e7), 1.0);
        assert_eq!(f32_spacing(f32::INFINITY), f32::INFINITY);
        assert!(f32_spacing(f32::NAN).is_nan());
    }

    #[test]
    fn spectral_norms() {
        let close = |a: f64, b: f64| (a - b).abs() < 1e-5 * b.max(1.0);
        let diag = Mat3A::from_diagonal(Vec3::new(1.0, 3.0, 0.5));
        assert!(close(spectral_norm(&diag), 3.0));
        assert!(close(spectral_norm(&diag.inverse()), 2.0));
        let rot = Mat3A::from_quat(Quat::from_axis_angle(
            Vec3::new(1.0, 2.0, 3.0).normalize(),
            0.7,
        ));
        assert!(close(spectral_norm(&rot), 1.0));
        assert!(close(spectral_norm(&(rot * diag)), 3.0));
        assert!(close(spectral_norm(&(Mat3A::IDENTITY * 1e-3)), 1e-3));
        // A shear: [[1, 1], [0, 1]] has singular values (sqrt(5) +- 1) / 2.
        let shear = Mat3A::from_cols(
            Vec3::X.into(),
            Vec3::new(1.0, 1.0, 0.0).into(),
            Vec3::Z.into(),
        );
        assert!(close(spectral_norm(&shear), (5f64.sqrt() + 1.0) / 2.0));
    }
}
