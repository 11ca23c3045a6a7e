//! Camera paths: keyed eye and target positions, and the view frustum a
//! camera sees.

use glam::{Mat4, Vec3, Vec4};

use crate::error::SceneError;

/// A camera at one moment.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    /// Eye position.
    pub eye: Vec3,
    /// The point looked at.
    pub target: Vec3,
    /// Vertical field of view, radians.
    pub fov_y: f32,
}

impl Camera {
    /// World-to-clip transform (right-handed, +Y up, depth 0..1) for an
    /// `aspect` (width / height), `near` and `far` plane.
    pub fn view_projection(&self, aspect: f32, near: f32, far: f32) -> Mat4 {
        let up = if (self.target - self.eye).cross(Vec3::Y).length_squared() > 1e-12 {
            Vec3::Y
        } else {
            Vec3::Z
        };
        glam::camera::rh::proj::directx::perspective(self.fov_y, aspect, near, far)
            * glam::camera::rh::view::look_at_mat4(self.eye, self.target, up)
    }

    /// The frustum of [`view_projection`](Self::view_projection).
    pub fn frustum(&self, aspect: f32, near: f32, far: f32) -> Frustum {
        Frustum::from_matrix(self.view_projection(aspect, near, far))
    }
}

/// Six planes `(n, d)` with `n . p + d >= 0` inside.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Frustum {
    planes: [Vec4; 6],
}

impl Frustum {
    /// The planes of a world-to-clip matrix (depth 0..1).
    pub fn from_matrix(m: Mat4) -> Frustum {
        let r = [m.row(0), m.row(1), m.row(2), m.row(3)];
        let planes = [
            r[3] + r[0],
            r[3] - r[0],
            r[3] + r[1],
            r[3] - r[1],
            r[2],
            r[3] - r[2],
        ]
        .map(|p| p / p.truncate().length().max(f32::MIN_POSITIVE));
        Frustum { planes }
    }

    /// Whether a sphere at `center` of `radius` touches the frustum.
    pub fn touches_sphere(&self, center: Vec3, radius: f32) -> bool {
        self.planes
            .iter()
            .all(|p| p.truncate().dot(center) + p.w >= -radius)
    }
}

/// One key of a camera path.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CameraKey {
    /// Time, seconds.
    pub time: f32,
    /// Eye position.
    pub eye: Vec3,
    /// The point looked at.
    pub target: Vec3,
}

/// A camera moving through keys, interpolated with uniform Catmull-Rom
/// splines for smooth motion; it holds the first and last keys outside
/// their range (no looping).
#[derive(Clone, Debug, PartialEq)]
pub struct CameraPath {
    /// Keys, by strictly increasing time.
    pub keys: Vec<CameraKey>,
    /// Vertical field of view, radians.
    pub fov_y: f32,
}

impl CameraPath {
    /// Checks there is a key, times increase strictly, everything is finite
    /// and the field of view lies in (0, pi).
    pub fn validate(&self) -> Result<(), SceneError> {
        let bad = |reason: &str| SceneError::Camera {
            reason: reason.to_string(),
        };
        if self.keys.is_empty() {
            return Err(bad("the path has no keys"));
        }
        if !(self.fov_y > 0.0 && self.fov_y < std::f32::consts::PI) {
            return Err(bad("field of view is not in (0, pi)"));
        }
        if self
            .keys
            .iter()
            .any(|k| !k.time.is_finite() || !k.eye.is_finite() || !k.target.is_finite())
        {
            return Err(bad("a key is not finite"));
        }
        if self.keys.windows(2).any(|w| w[0].time >= w[1].time) {
            return Err(bad("key times do not increase strictly"));
        }
        if self.keys.iter().any(|k| k.eye == k.target) {
            return Err(bad("a key looks at its own eye"));
        }
        Ok(())
    }

    /// The last key's time.
    pub fn duration(&self) -> f32 {
        self.keys.last().map_or(0.0, |k| k.time)
    }

    /// The camera at time `t` (the path must be valid).
    pub fn at(&self, t: f32) -> Camera {
        let k = &self.keys;
        let next = k.partition_point(|key| key.time <= t);
        let (eye, target) = if next == 0 {
            (k[0].eye, k[0].target)
        } else if next >= k.len() {
            (k[k.len() - 1].eye, k[k.len() - 1].target)
        } else {
            let i = next - 1;
            let s = (t - k[i].time) / (k[next].time - k[i].time);
            let at = |j: isize| k[j.clamp(0, k.len() as isize - 1) as usize];
            let (a, b, c, d) = (
                at(i as isize - 1),
                at(i as isize),
                at(next as isize),
                at(next as isize + 1),
            );
            (
                catmull_rom(a.eye, b.eye, c.eye, d.eye, s),
                catmull_rom(a.target, b.target, c.target, d.target, s),
            )
        };
        Camera {
            eye,
            target,
            fov_y: self.fov_y,
        }
    }
}

/// Largest camera-path file [`CameraPath::load`] reads, bytes.
pub const MAX_CAMERA_PATH_BYTES: u64 = 4 << 20;

/// Most keys a camera-path file may hold.
pub const MAX_CAMERA_KEYS: usize = 100_000;

/// Field of view of a path that does not state one, degrees.
pub const DEFAULT_FOV_DEGREES: f32 = 50.0;

impl CameraPath {
    /// A camera that stays at `eye`, looking at `target`, with a vertical
    /// field of view of `fov_y` radians; validated.
    pub fn fixed(eye: Vec3, target: Vec3, fov_y: f32) -> Result<CameraPath, SceneError> {
        let path = CameraPath {
            keys: vec![CameraKey {
                time: 0.0,
                eye,
                target,
            }],
            fov_y,
        };
        path.validate()?;
        Ok(path)
    }

    /// Parses the text form of a camera path: one key per line as seven
    /// numbers, `time eye.x eye.y eye.z target.x target.y target.z`
    /// (seconds and scene units, separated by spaces, tabs or commas),
    /// and optionally one line `fov DEGREES` (vertical, default
    /// [`DEFAULT_FOV_DEGREES`]). Blank lines and text after `#` are
    /// ignored. Errors name the line; the path is validated (times
    /// strictly increasing) and holds at most [`MAX_CAMERA_KEYS`] keys.
    pub fn parse(text: &str) -> Result<CameraPath, SceneError> {
        let bad = |line: usize, reason: String| SceneError::Camera {
            reason: format!("line {line}: {reason}"),
        };
        let mut keys = Vec::new();
        let mut fov: Option<f32> = None;
        for (k, raw) in text.lines().enumerate() {
            let line = k + 1;
            let body = raw.split('#').next().unwrap_or("").trim();
            if body.is_empty() {
                continue;
            }
            let words: Vec<&str> = body
                .split(|c: char| c.is_whitespace() || c == ',')
                .filter(|w| !w.is_empty())
                .collect();
            // A line of commas alone has no words.
            let Some(first) = words.first() else {
                continue;
            };
            if first.eq_ignore_ascii_case("fov") {
                if fov.is_some() {
                    return Err(bad(line, "a second fov line".into()));
                }
                let [_, deg] = words[..] else {
                    return Err(bad(line, "expected `fov DEGREES`".into()));
                };
                let deg: f32 = deg
                    .parse()
                    .map_err(|_| bad(line, format!("fov `{deg}` is not a number")))?;
                if !(deg > 0.0 && deg < 180.0) {
                    return Err(bad(line, format!("fov {deg} is not in (0, 180) degrees")));
                }
                fov = Some(deg.to_radians());
                continue;
            }
            if words.len() != 7 {
                return Err(bad(
                    line,
                    format!(
                        "{} numbers; a key is `time eye.x eye.y eye.z target.x target.y target.z`",
                        words.len()
                    ),
                ));
            }
            let mut v = [0f32; 7];
            for (x, w) in v.iter_mut().zip(&words) {
                *x = w
                    .parse::<f32>()
                    .ok()
                    .filter(|x| x.is_finite())
                    .ok_or_else(|| bad(line, format!("`{w}` is not a finite number")))?;
            }
            if keys.len() == MAX_CAMERA_KEYS {
                return Err(bad(line, format!("more than {MAX_CAMERA_KEYS} keys")));
            }
            keys.push(CameraKey {
                time: v[0],
                eye: Vec3::new(v[1], v[2], v[3]),
                target: Vec3::new(v[4], v[5], v[6]),
            });
        }
        if keys.is_empty() {
            return Err(SceneError::Camera {
                reason: "the camera path has no keys".into(),
            });
        }
        let path = CameraPath {
            keys,
            fov_y: fov.unwrap_or(DEFAULT_FOV_DEGREES.to_radians()),
        };
        path.validate()?;
        Ok(path)
    }

    /// Reads and [`parse`](Self::parse)s a camera-path file: a regular
    /// file (a pipe or a device is not read) of at most
    /// [`MAX_CAMERA_PATH_BYTES`], in UTF-8; errors name the file.
    pub fn load(path: &std::path::Path) -> Result<CameraPath, SceneError> {
        let named = |reason: String| SceneError::Camera {
            reason: format!("{}: {reason}", path.display()),
        };
        let bytes = crate::import::obj::read_capped(path, MAX_CAMERA_PATH_BYTES).map_err(named)?;
        let text = String::from_utf8(bytes).map_err(|_| named("not UTF-8 text".into()))?;
        CameraPath::parse(&text).map_err(|e| match e {
            SceneError::Camera { reason } => named(reason),
            e => e,
        })
    }

    /// The text form [`parse`](Self::parse) reads back (the same keys and
    /// field of view, to f32 round-trip precision).
    pub fn to_text(&self) -> String {
        let mut out = format!(
            "# psao camera path: time eye.xyz target.xyz\nfov {}\n",
            self.fov_y.to_degrees()
        );
        for k in &self.keys {
            out.push_str(&format!(
                "{} {} {} {} {} {} {}\n",
                k.time, k.eye.x, k.eye.y, k.eye.z, k.target.x, k.target.y, k.target.z
            ));
        }
        out
    }
}

/// Uniform Catmull-Rom between `b` and `c` at `s` in `[0, 1]`.
fn catmull_rom(a: Vec3, b: Vec3, c: Vec3, d: Vec3, s: f32) -> Vec3 {
    let (s2, s3) = (s * s, s * s * s);
    ((b * 2.0)
        + (c - a) * s
        + (a * 2.0 - b * 5.0 + c * 4.0 - d) * s2
        + (b * 3.0 - a - c * 3.0 + d) * s3)
        * 0.5
}
