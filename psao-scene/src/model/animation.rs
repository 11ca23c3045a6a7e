//! Node animation: keyframed translation, rotation, scale and morph
//! weight channels (glTF 2.0 animation samplers) with step, linear (slerp
//! for rotations) and cubic-spline interpolation.
//!
//! Every animation loops over its own duration (its last key time): at
//! scene time `t` it plays at `t mod duration`. An animation of duration 0
//! holds its first keys.

use glam::{Quat, Vec3};

use crate::error::SceneError;
use crate::model::node::{Trs, normalize_quat};

/// How values between two keys are found.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Interpolation {
    /// The value of the key at or before the time.
    Step,
    /// Linear for translation and scale, spherical linear (shortest arc)
    /// for rotations.
    Linear,
    /// Cubic Hermite spline; each key holds an in-tangent, a value and an
    /// out-tangent (glTF `CUBICSPLINE`). Rotations are renormalized.
    CubicSpline,
}

/// The keyed values of a channel: one per key, or three per key (in-tangent,
/// value, out-tangent) for [`Interpolation::CubicSpline`].
#[derive(Clone, Debug, PartialEq)]
pub enum Keys {
    /// Node translations.
    Translation(Vec<Vec3>),
    /// Node rotations (unit quaternions).
    Rotation(Vec<Quat>),
    /// Node scales.
    Scale(Vec<Vec3>),
    /// Morph target weights of the node's mesh: `targets` values per key
    /// (per tangent and value for a cubic spline), key after key.
    Weights {
        /// Weights per key (the mesh's number of targets), at least 1.
        targets: usize,
        /// The weights, `targets` at a time.
        values: Vec<f32>,
    },
}

impl Keys {
    fn len(&self) -> usize {
        match self {
            Keys::Translation(v) | Keys::Scale(v) => v.len(),
            Keys::Rotation(v) => v.len(),
            Keys::Weights { targets, values } => values.len() / (*targets).max(1),
        }
    }

    fn is_finite(&self) -> bool {
        match self {
            Keys::Translation(v) | Keys::Scale(v) => v.iter().all(|x| x.is_finite()),
            Keys::Rotation(v) => v.iter().all(|q| q.is_finite()),
            Keys::Weights { values, .. } => values.iter().all(|x| x.is_finite()),
        }
    }
}

/// One animated property of one node.
#[derive(Clone, Debug, PartialEq)]
pub struct Channel {
    /// The node it drives (index into [`Scene::nodes`](crate::Scene::nodes)).
    pub node: usize,
    /// Key times in seconds, strictly increasing, not negative.
    pub times: Vec<f32>,
    /// The keyed values.
    pub keys: Keys,
    /// How values between keys are found.
    pub interpolation: Interpolation,
}

/// A set of channels that play together.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Animation {
    /// Name (for messages).
    pub name: String,
    /// The channels.
    pub channels: Vec<Channel>,
}

impl Channel {
    /// Checks the node index, key times and value counts. `animation` and
    /// `channel` name it in errors.
    pub fn validate(
        &self,
        nodes: usize,
        animation: usize,
        channel: usize,
    ) -> Result<(), SceneError> {
        let bad = |reason: String| SceneError::Animation {
            animation,
            channel,
            reason,
        };
        if self.node >= nodes {
            return Err(bad(format!("drives node {} of {nodes}", self.node)));
        }
        if self.times.is_empty() {
            return Err(bad("has no keys".into()));
        }
        if !self.times.iter().all(|t| t.is_finite() && *t >= 0.0) {
            return Err(bad("a key time is negative or not finite".into()));
        }
        if self.times.windows(2).any(|w| w[0] >= w[1]) {
            return Err(bad("key times are not strictly increasing".into()));
        }
        let per_key = match self.interpolation {
            Interpolation::CubicSpline => 3,
            _ => 1,
        };
        if let Keys::Weights { targets, values } = &self.keys
            && (*targets == 0 || values.len() % targets != 0)
        {
            return Err(bad(format!(
                "{} weights is not a whole number of keys of {targets} targets",
                values.len()
            )));
        }
        if self.keys.len() != self.times.len() * per_key {
            return Err(bad(format!(
                "{} values for {} keys ({} per key)",
                self.keys.len(),
                self.times.len(),
                per_key
            )));
        }
        if !self.keys.is_finite() {
            return Err(bad("a value is not finite".into()));
        }
        if let Keys::Rotation(q) = &self.keys {
            // Tangents of a cubic spline need not be unit; values must.
            let values = q.iter().skip(per_key / 2).step_by(per_key);
            if values.into_iter().any(|q| (q.length() - 1.0).abs() > 1e-2) {
                return Err(bad("a rotation is not a unit quaternion".into()));
            }
        }
        Ok(())
    }

    /// The last key time.
    pub fn duration(&self) -> f32 {
        self.times.last().copied().unwrap_or(0.0)
    }

    /// Sets the property of `trs` it drives to its value at time `t`
    /// (clamped to the keys); a weights channel leaves `trs` as it is
    /// (see [`weights`](Self::weights)). The channel must be valid.
    pub fn apply(&self, t: f32, trs: &mut Trs) {
        let (i, s, dt) = self.locate(t);
        match &self.keys {
            Keys::Translation(v) => trs.translation = self.vec3(v, i, s, dt),
            Keys::Scale(v) => trs.scale = self.vec3(v, i, s, dt),
            Keys::Rotation(q) => trs.rotation = self.quat(q, i, s, dt),
            Keys::Weights { .. } => {}
        }
    }

    /// For a weights channel, its morph weights at time `t` (clamped to the
    /// keys) into `out`; other channels leave `out` as it is. The channel
    /// must be valid.
    pub fn weights(&self, t: f32, out: &mut Vec<f32>) {
        let Keys::Weights { targets, values } = &self.keys else {
            return;
        };
        let (i, s, dt) = self.locate(t);
        let n = *targets;
        let at = |key: usize| &values[key * n..(key + 1) * n];
        let last = self.times.len() - 1;
        out.clear();
        match self.interpolation {
            Interpolation::Step => out.extend_from_slice(at(i)),
            Interpolation::Linear if i == last => out.extend_from_slice(at(i)),
            Interpolation::Linear => {
                out.extend(at(i).iter().zip(at(i + 1)).map(|(a, b)| a + (b - a) * s))
            }
            Interpolation::CubicSpline if i == last => out.extend_from_slice(at(3 * i + 1)),
            Interpolation::CubicSpline => {
                let h = hermite(s);
                let (p0, m0, m1, p1) = (at(3 * i + 1), at(3 * i + 2), at(3 * i + 3), at(3 * i + 4));
                out.extend(
                    (0..n).map(|k| {
                        p0[k] * h[0] + m0[k] * dt * h[1] + p1[k] * h[2] + m1[k] * dt * h[3]
                    }),
                );
            }
        }
    }

    /// The key at or before `t`, the fraction `s` in `[0, 1]` towards the
    /// next key, and the time between the two keys.
    fn locate(&self, t: f32) -> (usize, f32, f32) {
        let n = self.times.len();
        let next = self.times.partition_point(|&k| k <= t);
        if next == 0 {
            return (0, 0.0, 0.0);
        }
        if next >= n {
            return (n - 1, 0.0, 0.0);
        }
        let (a, b) = (self.times[next - 1], self.times[next]);
        let dt = b - a;
        (next - 1, ((t - a) / dt).clamp(0.0, 1.0), dt)
    }

    fn vec3(&self, v: &[Vec3], i: usize, s: f32, dt: f32) -> Vec3 {
        let last = self.times.len() - 1;
        match self.interpolation {
            Interpolation::Step => v[i],
            Interpolation::Linear if i == last => v[i],
            Interpolation::Linear => v[i].lerp(v[i + 1], s),
            Interpolation::CubicSpline if i == last => v[3 * i + 1],
            Interpolation::CubicSpline => {
                let (p0, m0) = (v[3 * i + 1], v[3 * i + 2] * dt);
                let (p1, m1) = (v[3 * i + 4], v[3 * i + 3] * dt);
                let h = hermite(s);
                p0 * h[0] + m0 * h[1] + p1 * h[2] + m1 * h[3]
            }
        }
    }

    fn quat(&self, q: &[Quat], i: usize, s: f32, dt: f32) -> Quat {
        let last = self.times.len() - 1;
        let q = match self.interpolation {
            Interpolation::Step => q[i],
            Interpolation::Linear if i == last => q[i],
            Interpolation::Linear => normalize_quat(q[i]).slerp(normalize_quat(q[i + 1]), s),
            Interpolation::CubicSpline if i == last => q[3 * i + 1],
            Interpolation::CubicSpline => {
                let (p0, m0) = (q[3 * i + 1], q[3 * i + 2] * dt);
                let (p1, m1) = (q[3 * i + 4], q[3 * i + 3] * dt);
                let h = hermite(s);
                p0 * h[0] + m0 * h[1] + p1 * h[2] + m1 * h[3]
            }
        };
        normalize_quat(q)
    }
}

/// The four cubic Hermite basis weights at `s`.
fn hermite(s: f32) -> [f32; 4] {
    let (s2, s3) = (s * s, s * s * s);
    [
        2.0 * s3 - 3.0 * s2 + 1.0,
        s3 - 2.0 * s2 + s,
        -2.0 * s3 + 3.0 * s2,
        s3 - s2,
    ]
}

impl Animation {
    /// The last key time over all channels.
    pub fn duration(&self) -> f32 {
        self.channels
            .iter()
            .map(Channel::duration)
            .fold(0.0, f32::max)
    }

    /// The time within the loop at scene time `t`.
    pub fn local_time(&self, t: f32) -> f32 {
        // The same result as the f64 time's (the remainder is exact in
        // both; a negative time's sum rounds alike).
        self.local_time_at(t as f64)
    }

    /// The time within the loop at scene time `t`, taken in f64 (an f32
    /// time resolves 0.12 ms at 1,024 s and 7.8 ms at a day; an f64 one
    /// nanoseconds after years), then as the f32 the keys are sampled at.
    pub fn local_time_at(&self, t: f64) -> f32 {
        let d = self.duration();
        if d > 0.0 && t.is_finite() {
            t.rem_euclid(d as f64) as f32
        } else {
            0.0
        }
    }

    /// Sets every driven property of `nodes` to its value at scene time `t`
    /// (looping). The animation must be valid for `nodes`.
    pub fn apply(&self, t: f32, nodes: &mut [Trs]) {
        self.apply_at(t as f64, nodes);
    }

    /// [`apply`](Self::apply) at an f64 scene time
    /// ([`local_time_at`](Self::local_time_at)).
    pub fn apply_at(&self, t: f64, nodes: &mut [Trs]) {
        let local = self.local_time_at(t);
        for c in &self.channels {
            if let Some(trs) = nodes.get_mut(c.node) {
                c.apply(local, trs);
            }
        }
    }

    /// Sets the morph weights of every node a weights channel drives to
    /// their values at scene time `t` (looping): `weights[node]` takes
    /// them; nodes no channel drives keep theirs. The animation must be
    /// valid.
    pub fn apply_weights(&self, t: f32, weights: &mut [Vec<f32>]) {
        self.apply_weights_at(t as f64, weights);
    }

    /// [`apply_weights`](Self::apply_weights) at an f64 scene time
    /// ([`local_time_at`](Self::local_time_at)).
    pub fn apply_weights_at(&self, t: f64, weights: &mut [Vec<f32>]) {
        let local = self.local_time_at(t);
        for c in &self.channels {
            if let (Keys::Weights { .. }, Some(w)) = (&c.keys, weights.get_mut(c.node)) {
                c.weights(local, w);
            }
        }
    }

    /// Whether it poses its nodes alike at the end of its loop and at the
    /// start of the next (every channel's value at its duration equals
    /// its value at 0, to 1e-6 of the value; a rotation's quaternion, or
    /// its negation, to 1e-6 in each part): where it does, its loop's
    /// restart is no jump of
    /// the pose (a wheel turning a whole turn a loop). The animation must
    /// be valid.
    pub fn wraps_smoothly(&self) -> bool {
        let d = self.duration();
        let near = |a: f32, b: f32| (a - b).abs() <= 1e-6 * (1.0 + a.abs().max(b.abs()));
        let near3 = |a: glam::Vec3, b: glam::Vec3| (0..3).all(|k| near(a[k], b[k]));
        let near4 =
            |a: glam::Quat, b: glam::Quat| (a - b).to_array().iter().all(|d| d.abs() <= 1e-6);
        self.channels.iter().all(|c| {
            let (mut start, mut end) = (Trs::default(), Trs::default());
            c.apply(0.0, &mut start);
            c.apply(d, &mut end);
            let (mut w0, mut w1) = (Vec::new(), Vec::new());
            c.weights(0.0, &mut w0);
            c.weights(d, &mut w1);
            near3(start.translation, end.translation)
                && near3(start.scale, end.scale)
                && (near4(start.rotation, end.rotation) || near4(start.rotation, -end.rotation))
                && w0.len() == w1.len()
                && w0.iter().zip(&w1).all(|(&a, &b)| near(a, b))
        })
    }

    /// Whether a channel drives morph weights.
    pub fn drives_weights(&self) -> bool {
        self.channels
            .iter()
            .any(|c| matches!(c.keys, Keys::Weights { .. }))
    }

    /// A linear translation channel for `node` through `(time, position)`
    /// keys, as a one-channel animation (a convenience for scenes built in
    /// code).
    pub fn translation(name: &str, node: usize, keys: &[(f32, Vec3)]) -> Animation {
        Animation {
            name: name.to_string(),
            channels: vec![Channel {
                node,
                times: keys.iter().map(|k| k.0).collect(),
                keys: Keys::Translation(keys.iter().map(|k| k.1).collect()),
                interpolation: Interpolation::Linear,
            }],
        }
    }
}
