//! The bytes of a glTF file: its buffers (GLB binary chunk, `data:` URIs
//! or files next to the document), read once within
//! [`MAX_BUFFER_BYTES`], and its accessors, copied out of them with every
//! offset checked, within [`MAX_ACCESSOR_BYTES`] in all.

use std::io::Read;
use std::path::Path;

use base64::Engine;
use glam::Vec3;

use super::{MAX_ACCESSOR_BYTES, MAX_BUFFER_BYTES, gltf_error};
use crate::error::SceneError;

/// The file's buffers, and how many accessor bytes have been read from
/// them so far.
pub(super) struct Buffers {
    data: Vec<Vec<u8>>,
    read: std::cell::Cell<usize>,
}

pub(super) fn load_buffers(
    gltf: &gltf::Gltf,
    name: &str,
    base: Option<&Path>,
) -> Result<Buffers, SceneError> {
    let mut out = Vec::new();
    let mut total = 0usize;
    for buffer in gltf.buffers() {
        let element = format!("buffer {}", buffer.index());
        total = total.saturating_add(buffer.length());
        if total > MAX_BUFFER_BYTES {
            return Err(gltf_error(
                name,
                &element,
                format!("buffers declare more than the {MAX_BUFFER_BYTES} byte limit in all"),
            ));
        }
        let data = match buffer.source() {
            // glTF 2.0, 4.4.3.3: only the first buffer may be the GLB's
            // binary chunk.
            gltf::buffer::Source::Bin if buffer.index() != 0 => {
                return Err(gltf_error(
                    name,
                    &element,
                    "only buffer 0 may refer to the GLB binary chunk".into(),
                ));
            }
            gltf::buffer::Source::Bin => gltf
                .blob
                .as_deref()
                .map(|b| b[..b.len().min(buffer.length())].to_vec())
                .ok_or_else(|| {
                    gltf_error(
                        name,
                        &element,
                        "refers to a missing GLB binary chunk".into(),
                    )
                })?,
            gltf::buffer::Source::Uri(uri) if uri.starts_with("data:") => {
                let (_, payload) = uri
                    .split_once(";base64,")
                    .ok_or_else(|| gltf_error(name, &element, "data URI is not base64".into()))?;
                base64::engine::general_purpose::STANDARD
                    .decode(payload)
                    .map_err(|e| gltf_error(name, &element, format!("bad base64: {e}")))?
            }
            gltf::buffer::Source::Uri(uri) => {
                let dir = base.ok_or_else(|| {
                    gltf_error(
                        name,
                        &element,
                        format!("external buffer `{uri}` without a base folder"),
                    )
                })?;
                if uri.contains("..") || Path::new(uri).is_absolute() {
                    return Err(gltf_error(
                        name,
                        &element,
                        format!("buffer path `{uri}` leaves the model's folder"),
                    ));
                }
                // Read no more than the buffer declares, whatever the file holds.
                let mut data = Vec::new();
                std::fs::File::open(dir.join(uri))
                    .and_then(|f| f.take(buffer.length() as u64).read_to_end(&mut data))
                    .map_err(|e| gltf_error(name, &element, format!("`{uri}`: {e}")))?;
                data
            }
        };
        if data.len() < buffer.length() {
            return Err(gltf_error(
                name,
                &element,
                format!("holds {} bytes, declares {}", data.len(), buffer.length()),
            ));
        }
        out.push(data);
    }
    Ok(Buffers {
        data: out,
        read: std::cell::Cell::new(0),
    })
}

/// The raw elements of an accessor, each `size` bytes.
pub(super) struct Elements {
    bytes: Vec<u8>,
    size: usize,
    kind: gltf::accessor::DataType,
    normalized: bool,
}

impl Elements {
    /// Every component as f32: floats as they are, normalized integers
    /// mapped to [0, 1] or [-1, 1] (glTF 2.0, 3.11), other integers as
    /// their value.
    pub(super) fn floats(&self) -> Vec<f32> {
        use gltf::accessor::DataType;
        let b = &self.bytes;
        let n = self.normalized;
        match self.kind {
            DataType::F32 => b
                .chunks_exact(4)
                .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect(),
            DataType::U32 => b
                .chunks_exact(4)
                .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]) as f32)
                .collect(),
            DataType::U8 => b
                .iter()
                .map(|&c| if n { c as f32 / 255.0 } else { c as f32 })
                .collect(),
            DataType::I8 => b
                .iter()
                .map(|&c| {
                    let c = c as i8 as f32;
                    if n { (c / 127.0).max(-1.0) } else { c }
                })
                .collect(),
            DataType::U16 => b
                .chunks_exact(2)
                .map(|c| {
                    let c = u16::from_le_bytes([c[0], c[1]]) as f32;
                    if n { c / 65535.0 } else { c }
                })
                .collect(),
            DataType::I16 => b
                .chunks_exact(2)
                .map(|c| {
                    let c = i16::from_le_bytes([c[0], c[1]]) as f32;
                    if n { (c / 32767.0).max(-1.0) } else { c }
                })
                .collect(),
        }
    }

    pub(super) fn vec3(&self) -> Vec<Vec3> {
        self.bytes
            .chunks_exact(12)
            .map(|c| {
                let f = |i: usize| f32::from_le_bytes([c[i], c[i + 1], c[i + 2], c[i + 3]]);
                Vec3::new(f(0), f(4), f(8))
            })
            .collect()
    }

    pub(super) fn u32s(&self) -> Result<Vec<u32>, String> {
        use gltf::accessor::DataType;
        let c = self.bytes.chunks_exact(self.size);
        Ok(match self.kind {
            DataType::U8 => c.map(|b| b[0] as u32).collect(),
            DataType::U16 => c.map(|b| u16::from_le_bytes([b[0], b[1]]) as u32).collect(),
            DataType::U32 => c
                .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                .collect(),
            other => {
                return Err(format!(
                    "index component type {other:?} is not an unsigned integer"
                ));
            }
        })
    }
}

/// Copies an accessor's elements out of its buffer view with every offset,
/// stride and length checked (the gltf crate's reader asserts instead).
pub(super) fn read_accessor(
    acc: &gltf::Accessor<'_>,
    buffers: &Buffers,
) -> Result<Elements, String> {
    if acc.sparse().is_some() {
        return Err("sparse accessors are not supported".into());
    }
    let view = acc.view().ok_or("has no buffer view")?;
    let size = acc.size();
    let stride = view.stride().unwrap_or(size);
    if size == 0 || stride < size {
        return Err(format!(
            "stride {stride} is shorter than the element ({size} bytes)"
        ));
    }
    let data = buffers
        .data
        .get(view.buffer().index())
        .ok_or("refers to a missing buffer")?;
    let view_end = view
        .offset()
        .checked_add(view.length())
        .filter(|&e| e <= data.len())
        .ok_or("buffer view runs past its buffer")?;
    let start = view
        .offset()
        .checked_add(acc.offset())
        .ok_or("offset overflows")?;
    let count = acc.count();
    if count > 0 {
        let last = (count - 1)
            .checked_mul(stride)
            .and_then(|x| x.checked_add(start))
            .and_then(|x| x.checked_add(size))
            .ok_or("size overflows")?;
        if last > view_end {
            return Err(format!("{count} elements run past the buffer view"));
        }
    }
    let read = buffers
        .read
        .get()
        .saturating_add(count.saturating_mul(size));
    if read > MAX_ACCESSOR_BYTES {
        return Err(format!(
            "accessors would read more than the {MAX_ACCESSOR_BYTES} byte limit in all"
        ));
    }
    buffers.read.set(read);
    let mut bytes = Vec::with_capacity(count * size);
    for k in 0..count {
        let at = start + k * stride;
        bytes.extend_from_slice(&data[at..at + size]);
    }
    Ok(Elements {
        bytes,
        size,
        kind: acc.data_type(),
        normalized: acc.normalized(),
    })
}
