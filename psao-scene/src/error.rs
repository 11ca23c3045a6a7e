//! Errors of scene construction and processing.

use thiserror::Error;

/// What was wrong with a scene, mesh or parameter.
#[derive(Clone, Debug, PartialEq, Error)]
#[non_exhaustive]
pub enum SceneError {
    /// A mesh's index count is not a multiple of 3.
    #[error("mesh {mesh}: {len} indices is not a multiple of 3")]
    IndexCount {
        /// Mesh index.
        mesh: usize,
        /// Number of indices.
        len: usize,
    },
    /// A triangle refers to a vertex that does not exist.
    #[error("mesh {mesh}: triangle {triangle} refers to vertex {index} of {vertices}")]
    IndexOutOfRange {
        /// Mesh index.
        mesh: usize,
        /// Triangle index.
        triangle: usize,
        /// The bad vertex index.
        index: u32,
        /// Number of vertices.
        vertices: usize,
    },
    /// Positions and normals differ in length.
    #[error("mesh {mesh}: {positions} positions but {normals} normals")]
    NormalCount {
        /// Mesh index.
        mesh: usize,
        /// Positions.
        positions: usize,
        /// Normals.
        normals: usize,
    },
    /// A vertex position or normal is NaN or infinite.
    #[error("mesh {mesh}: vertex {vertex} is not finite")]
    NonFiniteVertex {
        /// Mesh index.
        mesh: usize,
        /// Vertex index.
        vertex: usize,
    },
    /// An instance refers to a mesh that does not exist.
    #[error("instance {instance} refers to mesh {mesh} of {meshes}")]
    MeshOutOfRange {
        /// Instance index.
        instance: usize,
        /// The bad mesh index.
        mesh: usize,
        /// Number of meshes.
        meshes: usize,
    },
    /// An instance transform is not finite, or is singular relative to its
    /// own scale ([`crate::MIN_TRANSFORM_RATIO`]).
    #[error(
        "instance {instance}: transform is not finite or not invertible (singular, or sheared almost flat: |det| below 1e-6 of the product of its column lengths)"
    )]
    BadTransform {
        /// Instance index.
        instance: usize,
    },
    /// An AO backend ([`crate::AoBackend`]) failed.
    #[error("AO backend {backend}: {reason}")]
    Backend {
        /// The backend's name.
        backend: String,
        /// What went wrong.
        reason: String,
    },
    /// A parameter is out of its range.
    #[error("parameter `{name}` = {value} is out of range: {rule}")]
    Parameter {
        /// Parameter name.
        name: &'static str,
        /// Its value.
        value: f64,
        /// The rule it breaks.
        rule: &'static str,
    },
    /// The scene at this density would give more points than the
    /// configured budget ([`crate::PipelineConfig::max_points`]).
    #[error(
        "the scene would give about {estimated} points at this density, over the budget of {max} (lower the density, or raise PipelineConfig::max_points where the memory is there: about 100 bytes a point)"
    )]
    TooManyPoints {
        /// Points the scene's area and the density would keep, estimated
        /// before any is made.
        estimated: u64,
        /// The budget.
        max: u64,
    },
    /// The laid-out grid breaks a rule of the wire format.
    #[error("instance {instance}: grid definition rejected: {error}")]
    Grid {
        /// Instance index.
        instance: usize,
        /// The rule.
        error: psao_codec::DefError,
    },
    /// A glTF file could not be read or holds something unsupported.
    #[error("{file}: {element}: {reason}")]
    Gltf {
        /// The file (or the name given for in-memory data).
        file: String,
        /// The element at fault (`document`, `buffer 0`, `mesh 2 primitive 0`, ...).
        element: String,
        /// What was wrong.
        reason: String,
    },
    /// An OBJ file (or its material library) is malformed or unsafe to
    /// load.
    #[error("OBJ {file}: {element}: {reason}")]
    Obj {
        /// The file (or the name given for in-memory data).
        file: String,
        /// The element at fault (`file`, `document`, `object 2 (name)`).
        element: String,
        /// What was wrong.
        reason: String,
    },
    /// A scene file of a format psao does not read.
    #[error("unsupported scene format: expected .gltf, .glb or .obj ({file})")]
    UnsupportedFormat {
        /// The file.
        file: String,
    },
    /// The codec refused a point or a frame.
    #[error("encoding failed: {0}")]
    Encode(#[from] psao_codec::EncodeError),
    /// Points and normals differ in length.
    #[error("{points} points but {normals} normals")]
    LengthMismatch {
        /// Points.
        points: usize,
        /// Normals.
        normals: usize,
    },
    /// The records of what clients hold differ in number from the points.
    #[error("{points} points but {sent} records of what clients hold")]
    SentCount {
        /// Points.
        points: usize,
        /// Records ([`psao_codec::SentPoint`]).
        sent: usize,
    },
    /// A node, skin, mesh attribute or instance reference is invalid.
    #[error("{element}: {reason}")]
    Element {
        /// The element (`node 3 (arm)`, `skin 0`, `mesh 2 skin weights`, ...).
        element: String,
        /// What was wrong.
        reason: String,
    },
    /// An animation channel is invalid.
    #[error("animation {animation} channel {channel}: {reason}")]
    Animation {
        /// Animation index.
        animation: usize,
        /// Channel index.
        channel: usize,
        /// What was wrong.
        reason: String,
    },
    /// The camera path is invalid.
    #[error("camera path: {reason}")]
    Camera {
        /// What was wrong.
        reason: String,
    },
    /// f32 cannot place an instance finely enough for AO: the spacing of
    /// f32 values at its largest coordinate is above a limit set by the AO
    /// radius or its point spacing (see [`check_precision`](crate::check_precision)).
    #[error(
        "instance {instance}: coordinate {coordinate} is too far from the origin for f32: \
         values there are {spacing} apart, more than the limit {limit} ({reason})"
    )]
    Precision {
        /// Instance index.
        instance: usize,
        /// The largest absolute coordinate it reaches (world or local, as
        /// `reason` says).
        coordinate: f32,
        /// The f32 spacing there (in local units for the rule that maps
        /// world positions into local space).
        spacing: f32,
        /// The largest spacing allowed.
        limit: f32,
        /// Which rule, the lengths it compares, and what to change.
        reason: String,
    },
    /// The grid would need more cells than a 32-bit key allows, or a table
    /// or pool beyond the receivers' default limits.
    #[error("instance {instance}: grid too large for 32-bit keys even at the coarsest cell size")]
    GridTooLarge {
        /// Instance index.
        instance: usize,
    },
}

/// Checks a named setting: `value` must be finite and within
/// `min..=max`; otherwise a [`SceneError::Parameter`] naming it and what
/// it must be (`what`).
pub fn check_param(
    name: &'static str,
    value: f64,
    min: f64,
    max: f64,
    rule: &'static str,
) -> Result<(), SceneError> {
    if value.is_finite() && value >= min && value <= max {
        Ok(())
    } else {
        Err(SceneError::Parameter { name, value, rule })
    }
}
