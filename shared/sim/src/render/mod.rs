//! Headless wgpu renderer of first-person greyscale views.
//!
//! All views of a call are drawn into one atlas texture (views tiled in a grid,
//! each through its own viewport and dynamic-offset camera uniform) in **one
//! submission**, copied into **one** readback buffer (rows padded to 256 bytes), and
//! mapped once. [`Frames`] hands out each view's rows straight from the mapped
//! buffer, so a consumer (an IPC sample, a PNG encoder) copies each frame exactly once.
//!
//! Invariant: while a [`Frames`] is alive the readback buffer stays mapped and
//! `render` cannot be called (it borrows the renderer mutably); dropping `Frames`
//! unmaps it.
//!
//! Adapters: a real GPU is preferred (Vulkan, then GL); without one, Mesa's CPU
//! rasterisers work — GL through EGL (llvmpipe, no install on most Linux images;
//! preferred, it measured faster here) or Vulkan through lavapipe
//! (`apt-get install -y mesa-vulkan-drivers`).

mod adapter;
pub mod dynamic;
mod frames;
mod ground;
pub mod mesh;

use std::sync::Arc;

use glam::{Mat4, Vec3};
use wgpu::util::DeviceExt;

use crate::region_map::RegionMap;
use crate::scene::Scene;

use adapter::{describe, pick_adapter};

pub use crate::error::RenderError;
pub use adapter::{BackendChoice, prepare_headless_env};
pub use dynamic::{DynamicBatch, Instance, Prototype};
pub use frames::Frames;
pub use mesh::SKY_SHADE;

/// Settings of a renderer.
#[derive(Debug, Clone, PartialEq)]
pub struct RendererConfig {
    /// Side of each square view in pixels.
    pub image_size: u32,
    /// Horizontal (= vertical) field of view in degrees.
    pub fov_deg: f32,
    /// Most views rendered in one call (atlas capacity).
    pub max_views: usize,
    /// Backend choice.
    pub backend: BackendChoice,
}

impl RendererConfig {
    /// The renderer of a simulator's observations: its image size and field of view.
    pub fn from_sim(sim: &crate::SimConfig, max_views: usize, backend: BackendChoice) -> RendererConfig {
        RendererConfig { image_size: sim.image_size, fov_deg: sim.fov_deg, max_views, backend }
    }
}

/// Per-view appearance (domain randomisation); [`Look::default`] is the plain scene.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Look {
    /// Added to the grey level after contrast.
    pub brightness: f32,
    /// Contrast gain around mid-grey.
    pub contrast: f32,
    /// Haze density per metre.
    pub haze: f32,
}

impl Default for Look {
    fn default() -> Self {
        Look { brightness: 0.0, contrast: 1.0, haze: 0.004 }
    }
}

impl Look {
    /// The domain-randomised look of an episode seeded with `seed`: brightness
    /// ±0.1, contrast 0.8–1.2, haze 0.002–0.008 per metre, all uniform.
    pub fn randomized(seed: u64) -> Look {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        Look {
            brightness: rng.random_range(-0.1..0.1),
            contrast: rng.random_range(0.8..1.2),
            haze: rng.random_range(0.002..0.008),
        }
    }
}

/// One camera to render.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraView {
    /// Camera x.
    pub x: f32,
    /// Camera y.
    pub y: f32,
    /// Camera height above ground.
    pub z: f32,
    /// Camera yaw (body yaw + head yaw), radians, 0 = east.
    pub yaw: f32,
    /// Appearance.
    pub look: Look,
}

/// Uniform block per view (std140-compatible).
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct ViewUniform {
    view_proj: [[f32; 4]; 4],
    eye: [f32; 4],
    look: [f32; 4],
}

const NEAR: f32 = 0.05;
const FAR: f32 = 1500.0;

/// The headless renderer.
pub struct Renderer {
    device: wgpu::Device,
    queue: wgpu::Queue,
    /// Obstacles and sky.
    flat_pipeline: wgpu::RenderPipeline,
    /// The textured ground.
    ground_pipeline: wgpu::RenderPipeline,
    /// Instanced prototypes (vehicles, walkers, lamps).
    instanced_pipeline: wgpu::RenderPipeline,
    /// Index ranges of the prototypes ([`dynamic::Prototype`] order).
    prototypes: [(u32, u32); dynamic::PROTOTYPES],
    /// Instances of the current call (grown as needed).
    instances: wgpu::Buffer,
    bind_group: wgpu::BindGroup,
    uniforms: wgpu::Buffer,
    uniform_stride: u64,
    vertices: wgpu::Buffer,
    indices: wgpu::Buffer,
    /// Indices of the scene; the six after them draw the sky quad.
    scene_indices: u32,
    /// Index ranges of the scene's objects, for per-view culling.
    parts: Vec<mesh::DrawRange>,
    color_view: wgpu::TextureView,
    color: wgpu::Texture,
    depth_view: wgpu::TextureView,
    readback: wgpu::Buffer,
    padded_bpr: u32,
    cols: u32,
    config: RendererConfig,
    proj: Mat4,
    adapter_info: wgpu::AdapterInfo,
    staging: Vec<u8>,
}

impl Renderer {
    /// Build the renderer for a scene: pick an adapter, upload the mesh and the
    /// ground texture, allocate the atlas for `config.max_views` views.
    pub fn new(scene: &Scene, map: &RegionMap, config: RendererConfig) -> Result<Renderer, RenderError> {
        let adapter = pick_adapter(config.backend)?;
        let adapter_info = adapter.get_info();
        let limits = adapter.limits();
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("pednav"),
            required_limits: limits.clone(),
            ..Default::default()
        }))
        .map_err(|e| RenderError::Device { adapter: describe(&adapter_info), message: e.to_string() })?;

        let size = config.image_size;
        let views = config.max_views.max(1);
        let cols = (views as f64).sqrt().ceil() as u32;
        let rows = (views as u32).div_ceil(cols);
        let (aw, ah) = (cols * size, rows * size);
        let limit = limits.max_texture_dimension_2d;
        if aw > limit || ah > limit {
            return Err(RenderError::AtlasTooLarge { views, size, needed: aw.max(ah), limit });
        }

        if map.nx as u64 > u64::from(limit) || map.ny as u64 > u64::from(limit) {
            return Err(RenderError::GroundTooLarge { width: map.nx as u32, height: map.ny as u32, limit });
        }
        let ground = ground::bake(scene, map);
        let ground_tex = device.create_texture_with_data(
            &queue,
            &wgpu::TextureDescriptor {
                label: Some("ground"),
                size: wgpu::Extent3d { width: ground.width, height: ground.height, depth_or_array_layers: 1 },
                mip_level_count: ground.mip_levels,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format: wgpu::TextureFormat::R8Unorm,
                usage: wgpu::TextureUsages::TEXTURE_BINDING,
                view_formats: &[],
            },
            wgpu::util::TextureDataOrder::LayerMajor,
            &ground.data,
        );
        let ground_view = ground_tex.create_view(&Default::default());
        let sampler = device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("ground"),
            address_mode_u: wgpu::AddressMode::ClampToEdge,
            address_mode_v: wgpu::AddressMode::ClampToEdge,
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            mipmap_filter: wgpu::MipmapFilterMode::Linear,
            anisotropy_clamp: 1,
            ..Default::default()
        });

        let mut mesh = mesh::build(scene, map);
        let parts = mesh.parts.clone();
        let scene_indices = mesh.indices.len() as u32;
        // The sky quad goes after the scene; it is drawn only for views whose look differs
        // from the default (the clear colour already is the default sky).
        let sky_base = mesh.vertices.len() as u32;
        mesh.vertices.extend_from_slice(&mesh::sky_quad());
        mesh.indices.extend_from_slice(&[0, 1, 2, 0, 2, 3].map(|k| sky_base + k));
        // The moving things' prototypes after the sky: the scene's own ranges stay as they were.
        let mut protos = mesh::MeshBuilder {
            vertices: std::mem::take(&mut mesh.vertices),
            indices: std::mem::take(&mut mesh.indices),
        };
        let prototypes = dynamic::build_prototypes(&mut protos);
        mesh.vertices = protos.vertices;
        mesh.indices = protos.indices;
        let vertices = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("scene mesh"),
            contents: bytemuck::cast_slice(&mesh.vertices),
            usage: wgpu::BufferUsages::VERTEX,
        });
        let indices = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("scene indices"),
            contents: bytemuck::cast_slice(&mesh.indices),
            usage: wgpu::BufferUsages::INDEX,
        });

        let align = limits.min_uniform_buffer_offset_alignment as u64;
        let uniform_stride = (std::mem::size_of::<ViewUniform>() as u64).div_ceil(align) * align;
        let uniforms = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("view uniforms"),
            size: uniform_stride * views as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });

        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("view"),
            entries: &[
                wgpu::BindGroupLayoutEntry {
                    binding: 0,
                    visibility: wgpu::ShaderStages::VERTEX_FRAGMENT,
                    ty: wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Uniform,
                        has_dynamic_offset: true,
                        min_binding_size: wgpu::BufferSize::new(std::mem::size_of::<ViewUniform>() as u64),
                    },
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 1,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Float { filterable: true },
                        view_dimension: wgpu::TextureViewDimension::D2,
                        multisampled: false,
                    },
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 2,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Filtering),
                    count: None,
                },
            ],
        });
        let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("view"),
            layout: &layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                        buffer: &uniforms,
                        offset: 0,
                        size: wgpu::BufferSize::new(std::mem::size_of::<ViewUniform>() as u64),
                    }),
                },
                wgpu::BindGroupEntry { binding: 1, resource: wgpu::BindingResource::TextureView(&ground_view) },
                wgpu::BindGroupEntry { binding: 2, resource: wgpu::BindingResource::Sampler(&sampler) },
            ],
        });

        let shader = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("pednav shader"),
            source: wgpu::ShaderSource::Wgsl(include_str!("shader.wgsl").into()),
        });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("pednav"),
            bind_group_layouts: &[Some(&layout)],
            ..Default::default()
        });
        let vertex_layout = wgpu::VertexBufferLayout {
            array_stride: std::mem::size_of::<mesh::Vertex>() as u64,
            step_mode: wgpu::VertexStepMode::Vertex,
            attributes: &wgpu::vertex_attr_array![
                0 => Float32x3, 1 => Float32x2, 2 => Float32, 3 => Float32, 4 => Float32x4, 5 => Float32x4
            ],
        };
        let make = |vertex: &str, fragment: &str, buffers: &[Option<wgpu::VertexBufferLayout<'_>>]| {
            device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                label: Some(fragment),
                layout: Some(&pipeline_layout),
                vertex: wgpu::VertexState {
                    module: &shader,
                    entry_point: Some(vertex),
                    compilation_options: Default::default(),
                    buffers,
                },
                primitive: wgpu::PrimitiveState { cull_mode: None, ..Default::default() },
                depth_stencil: Some(wgpu::DepthStencilState {
                    format: wgpu::TextureFormat::Depth32Float,
                    depth_write_enabled: Some(true),
                    depth_compare: Some(wgpu::CompareFunction::Less),
                    stencil: Default::default(),
                    bias: Default::default(),
                }),
                multisample: Default::default(),
                fragment: Some(wgpu::FragmentState {
                    module: &shader,
                    entry_point: Some(fragment),
                    compilation_options: Default::default(),
                    targets: &[Some(wgpu::ColorTargetState {
                        format: wgpu::TextureFormat::R8Unorm,
                        blend: None,
                        write_mask: wgpu::ColorWrites::ALL,
                    })],
                }),
                multiview_mask: None,
                cache: None,
            })
        };
        let flat_pipeline = make("vs_main", "fs_flat", &[Some(vertex_layout.clone())]);
        let ground_pipeline = make("vs_main", "fs_ground", &[Some(vertex_layout.clone())]);
        let instanced_pipeline =
            make("vs_instanced", "fs_flat", &[Some(vertex_layout.clone()), Some(dynamic::instance_layout())]);
        let instances = Self::instance_buffer(&device, 1024);

        let atlas_size = wgpu::Extent3d { width: aw, height: ah, depth_or_array_layers: 1 };
        let color = device.create_texture(&wgpu::TextureDescriptor {
            label: Some("atlas"),
            size: atlas_size,
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: wgpu::TextureFormat::R8Unorm,
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC,
            view_formats: &[],
        });
        let depth = device.create_texture(&wgpu::TextureDescriptor {
            label: Some("atlas depth"),
            size: atlas_size,
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: wgpu::TextureFormat::Depth32Float,
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT,
            view_formats: &[],
        });
        let padded_bpr = aw.div_ceil(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT) * wgpu::COPY_BYTES_PER_ROW_ALIGNMENT;
        let readback = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("atlas readback"),
            size: padded_bpr as u64 * ah as u64,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let fov = config.fov_deg.to_radians();
        let proj = glam::camera::rh::proj::directx::perspective(fov, 1.0, NEAR, FAR);
        tracing::debug!(adapter = %describe(&adapter_info), views, aw, ah, "renderer ready");
        Ok(Renderer {
            color_view: color.create_view(&Default::default()),
            color,
            depth_view: depth.create_view(&Default::default()),
            device,
            queue,
            flat_pipeline,
            ground_pipeline,
            instanced_pipeline,
            prototypes,
            instances,
            bind_group,
            uniforms,
            uniform_stride,
            scene_indices,
            parts,
            vertices,
            indices,
            readback,
            padded_bpr,
            cols,
            staging: vec![0; (uniform_stride * views as u64) as usize],
            config,
            proj,
            adapter_info,
        })
    }

    /// "name (backend, device type)" of the adapter in use.
    pub fn adapter_description(&self) -> String {
        describe(&self.adapter_info)
    }

    /// The settings this renderer was built with.
    pub fn config(&self) -> &RendererConfig {
        &self.config
    }

    fn instance_buffer(device: &wgpu::Device, capacity: usize) -> wgpu::Buffer {
        device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("instances"),
            size: (capacity * std::mem::size_of::<Instance>()) as u64,
            usage: wgpu::BufferUsages::VERTEX | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        })
    }

    /// Render all `views` in one submission and map the result once.
    pub fn render(&mut self, views: &[CameraView]) -> Result<Frames<'_>, RenderError> {
        self.render_with(views, None)
    }

    /// Render all `views` with the moving things of `batch` (one range set per
    /// view, in the same order) in one submission, and map the result once.
    pub fn render_with(
        &mut self,
        views: &[CameraView],
        batch: Option<&DynamicBatch>,
    ) -> Result<Frames<'_>, RenderError> {
        let max = self.config.max_views.max(1);
        if views.len() > max {
            return Err(RenderError::TooManyViews { asked: views.len(), max });
        }
        if views.is_empty() {
            return Ok(Frames { view: None, renderer: self, count: 0 });
        }
        let size = self.config.image_size;
        for (i, v) in views.iter().enumerate() {
            let eye = Vec3::new(v.x, v.y, v.z);
            let dir = Vec3::new(v.yaw.cos(), v.yaw.sin(), 0.0);
            let view_m = glam::camera::rh::view::look_to_mat4(eye, dir, Vec3::Z);
            let u = ViewUniform {
                view_proj: (self.proj * view_m).to_cols_array_2d(),
                eye: [v.x, v.y, v.z, v.look.haze],
                look: [v.look.brightness, v.look.contrast, SKY_SHADE, 0.0],
            };
            let off = i * self.uniform_stride as usize;
            self.staging[off..off + std::mem::size_of::<ViewUniform>()].copy_from_slice(bytemuck::bytes_of(&u));
        }
        let used = views.len() as u64 * self.uniform_stride;
        self.queue.write_buffer(&self.uniforms, 0, &self.staging[..used as usize]);
        let batch = batch.filter(|b| !b.instances.is_empty());
        if let Some(b) = batch {
            if b.ranges.len() != views.len() {
                return Err(RenderError::BatchViews { batch: b.ranges.len(), views: views.len() });
            }
            let bytes = (b.instances.len() * std::mem::size_of::<Instance>()) as u64;
            if bytes > self.instances.size() {
                self.instances = Self::instance_buffer(&self.device, b.instances.len().next_power_of_two());
            }
            self.queue.write_buffer(&self.instances, 0, bytemuck::cast_slice(&b.instances));
        }

        let rows = (views.len() as u32).div_ceil(self.cols);
        let mut encoder = self.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("views") });
        {
            let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("views"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view: &self.color_view,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations {
                        load: wgpu::LoadOp::Clear(wgpu::Color { r: SKY_SHADE as f64, g: 0.0, b: 0.0, a: 1.0 }),
                        store: wgpu::StoreOp::Store,
                    },
                })],
                depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                    view: &self.depth_view,
                    depth_ops: Some(wgpu::Operations { load: wgpu::LoadOp::Clear(1.0), store: wgpu::StoreOp::Discard }),
                    stencil_ops: None,
                }),
                ..Default::default()
            });
            pass.set_vertex_buffer(0, self.vertices.slice(..));
            pass.set_index_buffer(self.indices.slice(..), wgpu::IndexFormat::Uint32);
            let fov = self.config.fov_deg.to_radians();
            let (ground, objects) = self.parts.split_last().expect("the mesh ends with the ground part");
            for (i, v) in views.iter().enumerate() {
                let i = i as u32;
                let (c, r) = (i % self.cols, i / self.cols);
                pass.set_viewport((c * size) as f32, (r * size) as f32, size as f32, size as f32, 0.0, 1.0);
                pass.set_bind_group(0, &self.bind_group, &[(i as u64 * self.uniform_stride) as u32]);
                // Obstacles first (runs of consecutive visible parts), so that early depth
                // testing skips the textured ground behind them.
                pass.set_pipeline(&self.flat_pipeline);
                let mut run: Option<(u32, u32)> = None;
                for p in objects.iter().filter(|p| mesh::part_visible(p, v.x, v.y, v.yaw, fov)) {
                    run = match run {
                        Some((s, e)) if e == p.start => Some((s, p.end)),
                        Some((s, e)) => {
                            pass.draw_indexed(s..e, 0, 0..1);
                            Some((p.start, p.end))
                        }
                        None => Some((p.start, p.end)),
                    };
                }
                if let Some((s, e)) = run {
                    pass.draw_indexed(s..e, 0, 0..1);
                }
                if v.look != Look::default() {
                    pass.draw_indexed(self.scene_indices..self.scene_indices + 6, 0, 0..1);
                }
                if let Some(b) = batch {
                    // Moving things before the ground, for the same early-depth reason.
                    pass.set_pipeline(&self.instanced_pipeline);
                    pass.set_vertex_buffer(1, self.instances.slice(..));
                    for (k, &(s, e)) in b.ranges[i as usize].iter().enumerate() {
                        if e > s {
                            let (is, ie) = self.prototypes[k];
                            pass.draw_indexed(is..ie, 0, s..e);
                        }
                    }
                }
                pass.set_pipeline(&self.ground_pipeline);
                pass.draw_indexed(ground.start..ground.end, 0, 0..1);
            }
        }
        let copy_height = rows * size;
        encoder.copy_texture_to_buffer(
            wgpu::TexelCopyTextureInfo {
                texture: &self.color,
                mip_level: 0,
                origin: wgpu::Origin3d::ZERO,
                aspect: wgpu::TextureAspect::All,
            },
            wgpu::TexelCopyBufferInfo {
                buffer: &self.readback,
                layout: wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(self.padded_bpr),
                    rows_per_image: Some(copy_height),
                },
            },
            wgpu::Extent3d { width: self.cols * size, height: copy_height, depth_or_array_layers: 1 },
        );
        self.queue.submit([encoder.finish()]);

        let bytes = self.padded_bpr as u64 * copy_height as u64;
        let status = Arc::new(std::sync::Mutex::new(None));
        let status_cb = status.clone();
        self.readback.slice(..bytes).map_async(wgpu::MapMode::Read, move |r| {
            *status_cb.lock().expect("map status lock") = Some(r);
        });
        self.device
            .poll(wgpu::PollType::Wait { submission_index: None, timeout: None })
            .map_err(|e| RenderError::Readback(e.to_string()))?;
        match status.lock().expect("map status lock").take() {
            Some(Ok(())) => {}
            Some(Err(e)) => return Err(RenderError::Readback(e.to_string())),
            None => return Err(RenderError::Readback("buffer map callback never ran".into())),
        }
        let view = self.readback.slice(..bytes).get_mapped_range().map_err(|e| RenderError::Readback(e.to_string()))?;
        Ok(Frames { view: Some(view), count: views.len(), renderer: self })
    }
}
