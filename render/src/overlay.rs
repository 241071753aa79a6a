//! [`Overlay`]: lines of text over a drawn image (the viewer's frame rate, GI latency, frame
//! sequence). Text is rasterised on the CPU with an 8 × 8 bitmap font into a small premultiplied
//! RGBA texture, uploaded only when the text changes, and drawn with one blended quad.

use bytemuck::{Pod, Zeroable};
use wgpu::util::DeviceExt;

use crate::error::RenderError;
use crate::renderer::{Target, compiling};
use crate::resources::bind_group;

/// The overlay's shader module.
pub const OVERLAY_SHADER: &str = include_str!("overlay.wgsl");

/// `OverlayParams` in `overlay.wgsl`: pixels.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Pod, Zeroable)]
pub struct OverlayParams {
    pub origin: [f32; 2],
    pub size: [f32; 2],
    pub target_size: [f32; 2],
    pub pad: [f32; 2],
}

const GLYPH: u32 = 8;
const MARGIN: u32 = 4;

/// Text over an image; see the module doc.
pub struct Overlay {
    pipelines: Vec<(wgpu::TextureFormat, wgpu::RenderPipeline)>,
    params: wgpu::Buffer,
    /// The text now uploaded, its texture's bind group and size in pixels.
    shown: Option<(Vec<String>, wgpu::BindGroup, [u32; 2])>,
    scale: u32,
}

impl Overlay {
    /// An overlay for targets of these formats; glyphs are drawn `scale` times 8 pixels.
    pub fn new(
        device: &wgpu::Device,
        formats: &[wgpu::TextureFormat],
        scale: u32,
    ) -> Result<Overlay, RenderError> {
        let _one = compiling();
        let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("overlay"),
            source: wgpu::ShaderSource::Wgsl(OVERLAY_SHADER.into()),
        });
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("overlay"),
            entries: &[
                wgpu::BindGroupLayoutEntry {
                    binding: 0,
                    visibility: wgpu::ShaderStages::VERTEX | wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Uniform,
                        has_dynamic_offset: false,
                        min_binding_size: None,
                    },
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 1,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Float { filterable: false },
                        view_dimension: wgpu::TextureViewDimension::D2,
                        multisampled: false,
                    },
                    count: None,
                },
            ],
        });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("overlay"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let pipelines = formats
            .iter()
            .map(|&format| {
                let pipeline = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                    label: Some("overlay"),
                    layout: Some(&pipeline_layout),
                    vertex: wgpu::VertexState {
                        module: &module,
                        entry_point: Some("vs_overlay"),
                        compilation_options: Default::default(),
                        buffers: &[],
                    },
                    primitive: wgpu::PrimitiveState {
                        topology: wgpu::PrimitiveTopology::TriangleStrip,
                        ..Default::default()
                    },
                    depth_stencil: None,
                    multisample: Default::default(),
                    fragment: Some(wgpu::FragmentState {
                        module: &module,
                        entry_point: Some("fs_overlay"),
                        compilation_options: Default::default(),
                        targets: &[Some(wgpu::ColorTargetState {
                            format,
                            blend: Some(wgpu::BlendState::PREMULTIPLIED_ALPHA_BLENDING),
                            write_mask: wgpu::ColorWrites::ALL,
                        })],
                    }),
                    multiview_mask: None,
                    cache: None,
                });
                (format, pipeline)
            })
            .collect();
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(RenderError::Shader(e.to_string()));
        }
        let params = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("overlay params"),
            size: std::mem::size_of::<OverlayParams>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        Ok(Overlay {
            pipelines,
            params,
            shown: None,
            scale: scale.max(1),
        })
    }

    /// Records `lines` over `target` at its top left (after the scene was drawn into it).
    pub fn draw(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        encoder: &mut wgpu::CommandEncoder,
        target: &Target<'_>,
        lines: &[String],
    ) -> Result<(), RenderError> {
        let pipeline = self
            .pipelines
            .iter()
            .find(|(f, _)| *f == target.format)
            .map(|(_, p)| p)
            .ok_or(RenderError::Format(target.format))?;
        if lines.iter().all(|l| l.is_empty()) {
            return Ok(());
        }
        if self.shown.as_ref().map(|s| &s.0[..]) != Some(lines) {
            let (width, height, rgba) = rasterise(lines, self.scale);
            let texture = device.create_texture_with_data(
                queue,
                &wgpu::TextureDescriptor {
                    label: Some("overlay text"),
                    size: wgpu::Extent3d {
                        width,
                        height,
                        depth_or_array_layers: 1,
                    },
                    mip_level_count: 1,
                    sample_count: 1,
                    dimension: wgpu::TextureDimension::D2,
                    format: wgpu::TextureFormat::Rgba8Unorm,
                    usage: wgpu::TextureUsages::TEXTURE_BINDING,
                    view_formats: &[],
                },
                wgpu::util::TextureDataOrder::LayerMajor,
                &rgba,
            );
            let view = texture.create_view(&Default::default());
            let group = bind_group(
                device,
                &pipeline.get_bind_group_layout(0),
                vec![
                    (0, self.params.as_entire_binding()),
                    (1, wgpu::BindingResource::TextureView(&view)),
                ],
            );
            self.shown = Some((lines.to_vec(), group, [width, height]));
        }
        let Some((_, group, [width, height])) = &self.shown else {
            return Ok(());
        };
        let params = OverlayParams {
            origin: [MARGIN as f32; 2],
            size: [*width as f32, *height as f32],
            target_size: [target.width as f32, target.height as f32],
            pad: [0.0; 2],
        };
        queue.write_buffer(&self.params, 0, bytemuck::bytes_of(&params));
        let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some("overlay"),
            color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                view: target.color,
                depth_slice: None,
                resolve_target: None,
                ops: wgpu::Operations {
                    load: wgpu::LoadOp::Load,
                    store: wgpu::StoreOp::Store,
                },
            })],
            depth_stencil_attachment: None,
            timestamp_writes: None,
            occlusion_query_set: None,
            multiview_mask: None,
        });
        pass.set_pipeline(pipeline);
        pass.set_bind_group(0, group, &[]);
        pass.draw(0..4, 0..1);
        Ok(())
    }
}

/// White glyphs on a translucent black panel, premultiplied; characters outside ASCII are `?`.
fn rasterise(lines: &[String], scale: u32) -> (u32, u32, Vec<u8>) {
    let cols = lines
        .iter()
        .map(|l| l.chars().count())
        .max()
        .unwrap_or(0)
        .max(1) as u32;
    let rows = lines.len().max(1) as u32;
    let pad = 2 * scale;
    let width = cols * GLYPH * scale + 2 * pad;
    let height = rows * (GLYPH + 2) * scale + 2 * pad;
    let mut rgba = [0u8, 0, 0, 160].repeat((width * height) as usize);
    for (row, line) in lines.iter().enumerate() {
        for (col, c) in line.chars().enumerate() {
            let code = if c.is_ascii() {
                c as usize
            } else {
                '?' as usize
            };
            let glyph = font8x8::legacy::BASIC_LEGACY[code];
            for (gy, bits) in glyph.iter().enumerate() {
                for gx in 0..GLYPH {
                    // Bit 0 is the leftmost pixel.
                    if bits & (1 << gx) == 0 {
                        continue;
                    }
                    for sy in 0..scale {
                        for sx in 0..scale {
                            let x = pad + (col as u32 * GLYPH + gx) * scale + sx;
                            let y = pad + (row as u32 * (GLYPH + 2) + gy as u32) * scale + sy;
                            let i = ((y * width + x) * 4) as usize;
                            rgba[i..i + 4].copy_from_slice(&[255, 255, 255, 255]);
                        }
                    }
                }
            }
        }
    }
    (width, height, rgba)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn text_is_rasterised_where_the_font_says() {
        let (w, h, rgba) = rasterise(&["I".to_string()], 1);
        assert_eq!((w, h), (8 + 4, 10 + 4));
        let lit = |x: u32, y: u32| rgba[((y * w + x) * 4) as usize] == 255;
        // 'I' in font8x8 is a vertical bar of columns 2..4 on rows 1..5 (0x1E top and bottom).
        let glyph = font8x8::legacy::BASIC_LEGACY['I' as usize];
        for (gy, bits) in glyph.iter().enumerate() {
            for gx in 0..8 {
                assert_eq!(
                    lit(2 + gx, 2 + gy as u32),
                    bits & (1 << gx) != 0,
                    "({gx}, {gy})"
                );
            }
        }
        // The panel is translucent black, premultiplied.
        assert_eq!(&rgba[0..4], &[0, 0, 0, 160]);
        // Non-ASCII becomes '?', not a panic.
        let (_, _, q) = rasterise(&["é".to_string()], 2);
        assert!(q.chunks(4).any(|p| p[0] == 255));
    }
}
