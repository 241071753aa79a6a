//! How fast the device reads its own memory: the figure `bench engines` compares a product's
//! effective bandwidth with, measured on the same device in the same run.

use std::time::Instant;

use bytemuck::{Pod, Zeroable};
use wgpu::util::DeviceExt;

use super::kernel::{Loops, pipeline_with, read_words, scoped};
use super::{GpuContext, GpuError};

const SOURCE: &str = include_str!("shaders/bandwidth.wgsl");
/// Threads per workgroup (`@workgroup_size` of `read_all`).
const WG: u64 = 256;

/// `Probe` in `bandwidth.wgsl`.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
pub struct Probe {
    pub len: u32,
    pub groups: u32,
}

/// The word the probe buffer holds at index `i`: every bit varies, so no compression or
/// zero-page shortcut can serve the reads.
pub fn pattern(i: u32) -> u32 {
    i.wrapping_mul(2_654_435_761) ^ 0x5bd1_e995
}

/// The CPU twin of the kernel's reduction: the wrapping sum of the words.
pub fn checksum(words: impl IntoIterator<Item = u32>) -> u32 {
    words.into_iter().fold(0u32, u32::wrapping_add)
}

/// One measurement: bytes read per second (best of the timed submissions) and the checksum of
/// the last dispatch, which must equal [`checksum`] of the buffer.
#[derive(Debug, Clone, Copy)]
pub struct Bandwidth {
    pub bytes_per_s: f64,
    pub bytes: u64,
    pub checksum: u32,
}

/// Read a buffer of about `bytes` (capped by the binding limit, a multiple of 16) `repeats`
/// times per submission, five submissions after a warm-up; the best submission's rate.
pub fn measure(ctx: &GpuContext, bytes: u64, repeats: u32) -> Result<Bandwidth, GpuError> {
    let device = &ctx.device;
    let limit = super::Split::of(device).binding_bytes;
    let bytes = bytes.min(limit) / 16 * 16;
    if bytes == 0 {
        return Err(GpuError::TooLarge {
            what: "bandwidth probe",
            needed: 16,
            limit,
        });
    }
    let words = (bytes / 4) as u32;
    let len = (bytes / 16) as u32;
    let groups = u64::from(len).div_ceil(WG).min(8192) as u32;
    let (buffers, error) = scoped(device, wgpu::ErrorFilter::OutOfMemory, || {
        let contents: Vec<u32> = (0..words).map(pattern).collect();
        let data = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("bandwidth probe"),
            contents: bytemuck::cast_slice(&contents),
            usage: wgpu::BufferUsages::STORAGE,
        });
        let sums = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("bandwidth sums"),
            size: u64::from(groups) * 4,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        let readback = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("bandwidth readback"),
            size: u64::from(groups) * 4,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let probe = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("bandwidth params"),
            contents: bytemuck::bytes_of(&Probe { len, groups }),
            usage: wgpu::BufferUsages::UNIFORM,
        });
        (data, sums, readback, probe)
    });
    if let Some(e) = error {
        return Err(GpuError::OutOfMemory {
            what: "bandwidth probe",
            message: e.to_string(),
        });
    }
    let (data, sums, readback, probe) = buffers;
    let pipeline = pipeline_with(device, "bandwidth", SOURCE, "read_all", &[], Loops::Counted)?;
    let group = device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: None,
        layout: &pipeline.get_bind_group_layout(0),
        entries: &[
            wgpu::BindGroupEntry {
                binding: 0,
                resource: probe.as_entire_binding(),
            },
            wgpu::BindGroupEntry {
                binding: 1,
                resource: data.as_entire_binding(),
            },
            wgpu::BindGroupEntry {
                binding: 2,
                resource: sums.as_entire_binding(),
            },
        ],
    });
    let submit = |times: u32, copy: bool| -> Result<f64, GpuError> {
        let mut encoder = device.create_command_encoder(&Default::default());
        {
            let mut pass = encoder.begin_compute_pass(&Default::default());
            pass.set_pipeline(&pipeline);
            pass.set_bind_group(0, &group, &[]);
            for _ in 0..times {
                pass.dispatch_workgroups(groups, 1, 1);
            }
        }
        if copy {
            encoder.copy_buffer_to_buffer(&sums, 0, &readback, 0, u64::from(groups) * 4);
        }
        let start = Instant::now();
        ctx.queue.submit([encoder.finish()]);
        device
            .poll(wgpu::PollType::wait_indefinitely())
            .map_err(|e| GpuError::Readback(e.to_string()))?;
        Ok(start.elapsed().as_secs_f64())
    };
    submit(1, false)?;
    let mut best = f64::INFINITY;
    for _ in 0..5 {
        best = best.min(submit(repeats.max(1), false)?);
    }
    submit(1, true)?;
    let partial = read_words(device, &readback, groups as usize)?;
    Ok(Bandwidth {
        bytes_per_s: (bytes * u64::from(repeats.max(1))) as f64 / best,
        bytes,
        checksum: checksum(partial),
    })
}
