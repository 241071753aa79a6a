//! Accessor data read by hand, every offset, stride and length checked against the buffer.
//!
//! The `gltf` crate's reader trusts values that its validation does not check (a zero count
//! underflows, a short buffer view is sliced past its end, a stride below the element size trips
//! an assertion), so geometry is read here instead. Every component type is accepted and
//! converted to `f64` (normalised integers scaled as the spec says), which also covers
//! `KHR_mesh_quantization`.

use gltf::accessor::{DataType, Dimensions};

/// Largest number of components one accessor may expand to: a guard against a tiny file that
/// claims billions of (sparse, zero-initialised) elements.
const MAX_COMPONENTS: usize = 1 << 28;

/// A buffer's bytes, or why they could not be read.
pub(crate) type BufferData<'a> = Result<std::borrow::Cow<'a, [u8]>, String>;

/// Why an accessor could not be read.
#[derive(Debug)]
pub(crate) enum ReadError {
    /// The buffer behind it could not be loaded; the whole import should fail.
    Buffer { buffer: usize, reason: String },
    /// The accessor itself is inconsistent with its data; skip what needs it.
    Invalid(String),
}

impl From<String> for ReadError {
    fn from(reason: String) -> Self {
        ReadError::Invalid(reason)
    }
}

/// The bytes of a buffer view, bounds-checked.
pub(crate) fn view_bytes<'b>(
    view: &gltf::buffer::View<'_>,
    buffers: &'b [BufferData<'_>],
) -> Result<&'b [u8], ReadError> {
    let buffer = view.buffer().index();
    let data = match buffers.get(buffer) {
        Some(Ok(data)) => data.as_ref(),
        Some(Err(reason)) => {
            return Err(ReadError::Buffer {
                buffer,
                reason: reason.clone(),
            });
        }
        None => return Err(format!("buffer {buffer} does not exist").into()),
    };
    let start = view.offset();
    let end = start.checked_add(view.length());
    end.and_then(|end| data.get(start..end)).ok_or_else(|| {
        format!(
            "buffer view {} (bytes {start}..+{}) runs past the end of buffer {buffer} ({} bytes)",
            view.index(),
            view.length(),
            data.len()
        )
        .into()
    })
}

/// Reads an accessor's elements as a flat vector of `count × components` values, each converted
/// by `conv`. Only scalar and vector types are accepted.
pub(crate) fn read<T: Copy>(
    accessor: &gltf::Accessor<'_>,
    buffers: &[BufferData<'_>],
    conv: impl Fn(f64) -> T,
) -> Result<Vec<T>, ReadError> {
    let dims = match accessor.dimensions() {
        Dimensions::Scalar => 1,
        Dimensions::Vec2 => 2,
        Dimensions::Vec3 => 3,
        Dimensions::Vec4 => 4,
        other => return Err(format!("accessor {} has type {other:?}", accessor.index()).into()),
    };
    let ty = accessor.data_type();
    let normalized = accessor.normalized();
    let element_size = dims * ty.size();
    let count = accessor.count();
    let total = count
        .checked_mul(dims)
        .filter(|&n| n <= MAX_COMPONENTS)
        .ok_or_else(|| {
            format!(
                "accessor {} is too large ({count} elements)",
                accessor.index()
            )
        })?;

    let mut out = Vec::with_capacity(total);
    match accessor.view() {
        Some(view) => {
            let bytes = view_bytes(&view, buffers)?;
            let stride = view.stride().unwrap_or(element_size);
            if stride < element_size {
                return Err(format!(
                    "accessor {}: byte stride {stride} is smaller than its element ({element_size} bytes)",
                    accessor.index()
                )
                .into());
            }
            let start = accessor.offset();
            let fits = count == 0
                || (count - 1)
                    .checked_mul(stride)
                    .and_then(|n| n.checked_add(start))
                    .and_then(|n| n.checked_add(element_size))
                    .is_some_and(|end| end <= bytes.len());
            if !fits {
                return Err(format!(
                    "accessor {} ({count} elements of {element_size} bytes, stride {stride}, offset \
                     {start}) runs past the end of buffer view {} ({} bytes)",
                    accessor.index(),
                    view.index(),
                    bytes.len()
                )
                .into());
            }
            for i in 0..count {
                let at = start + i * stride;
                let element = bytes.get(at..at + element_size).ok_or_else(|| {
                    format!("accessor {}: element {i} out of range", accessor.index())
                })?;
                out.extend(
                    element
                        .chunks_exact(ty.size())
                        .map(|c| conv(component(c, ty, normalized))),
                );
            }
        }
        None => out.resize(total, conv(0.0)),
    }

    if let Some(sparse) = accessor.sparse() {
        let n = sparse.count();
        let indices = sparse.indices();
        let index_type = match indices.index_type() {
            gltf::accessor::sparse::IndexType::U8 => DataType::U8,
            gltf::accessor::sparse::IndexType::U16 => DataType::U16,
            gltf::accessor::sparse::IndexType::U32 => DataType::U32,
        };
        let index_bytes = packed(
            view_bytes(&indices.view(), buffers)?,
            indices.offset(),
            n,
            index_type.size(),
        )
        .ok_or_else(|| format!("accessor {}: sparse indices out of range", accessor.index()))?;
        let values = sparse.values();
        let value_bytes = packed(
            view_bytes(&values.view(), buffers)?,
            values.offset(),
            n,
            element_size,
        )
        .ok_or_else(|| format!("accessor {}: sparse values out of range", accessor.index()))?;
        for (index, value) in index_bytes
            .chunks_exact(index_type.size())
            .zip(value_bytes.chunks_exact(element_size))
        {
            let index = component(index, index_type, false) as usize;
            if index >= count {
                return Err(format!(
                    "accessor {}: sparse index {index} out of range ({count} elements)",
                    accessor.index()
                )
                .into());
            }
            let target = &mut out[index * dims..(index + 1) * dims];
            for (slot, c) in target.iter_mut().zip(value.chunks_exact(ty.size())) {
                *slot = conv(component(c, ty, normalized));
            }
        }
    }
    Ok(out)
}

/// `n` tightly packed items of `size` bytes from `offset`, or `None` if they do not fit.
fn packed(bytes: &[u8], offset: usize, n: usize, size: usize) -> Option<&[u8]> {
    let end = n.checked_mul(size)?.checked_add(offset)?;
    bytes.get(offset..end)
}

/// One component; `c` holds exactly `ty.size()` bytes (callers split with `chunks_exact`).
fn component(c: &[u8], ty: DataType, normalized: bool) -> f64 {
    let bytes = |n: usize| -> [u8; 4] {
        let mut b = [0u8; 4];
        for (dst, src) in b.iter_mut().zip(c.iter().take(n)) {
            *dst = *src;
        }
        b
    };
    match ty {
        DataType::I8 => {
            let v = f64::from(bytes(1)[0] as i8);
            if normalized { (v / 127.0).max(-1.0) } else { v }
        }
        DataType::U8 => {
            let v = f64::from(bytes(1)[0]);
            if normalized { v / 255.0 } else { v }
        }
        DataType::I16 => {
            let b = bytes(2);
            let v = f64::from(i16::from_le_bytes([b[0], b[1]]));
            if normalized {
                (v / 32767.0).max(-1.0)
            } else {
                v
            }
        }
        DataType::U16 => {
            let b = bytes(2);
            let v = f64::from(u16::from_le_bytes([b[0], b[1]]));
            if normalized { v / 65535.0 } else { v }
        }
        DataType::U32 => {
            let v = f64::from(u32::from_le_bytes(bytes(4)));
            if normalized {
                v / f64::from(u32::MAX)
            } else {
                v
            }
        }
        DataType::F32 => f64::from(f32::from_le_bytes(bytes(4))),
    }
}
