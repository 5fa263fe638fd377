//! `assay-render`: the render role. Draws [`SceneSnapshot`]s headless with wgpu on whatever adapter
//! it finds — a real GPU, or Mesa's software Vulkan (lavapipe) where there is none — into RGB,
//! depth and instance segmentation from one render pass, and encodes PNGs and contact sheets.
//!
//! Owns: the GPU device, pipelines and readback. Never simulates and never does networking.

pub mod caption;
pub mod image;
pub mod imagery;
pub mod math;
pub mod mesh;
pub mod video;

use std::borrow::Cow;
use std::collections::HashMap;
use std::mem::size_of;

use assay_spec::scene::{
    EE_CAMERA, FIRST_OBJECT_SEGMENT, SEGMENT_SURFACE, SEGMENT_TOOL, SceneSnapshot,
    TOOL_HALF_EXTENTS,
};
use assay_spec::spec::{Camera, Shape, Surface, TABLE_CENTER, TABLE_HALF_EXTENTS};
use bytemuck::{Pod, Zeroable};
use serde::{Deserialize, Serialize};
use wgpu::util::DeviceExt;

use crate::math::{Mat4, mul, perspective, rotate, trs};
use crate::mesh::{MeshData, Vertex};

pub const ZNEAR: f32 = 0.01;
pub const ZFAR: f32 = 10.0;
const BACKGROUND: [f64; 3] = [0.86, 0.88, 0.91];
const TABLE_COLOR: [f32; 3] = [0.72, 0.62, 0.48];
const GROUND_COLOR: [f32; 3] = [0.55, 0.57, 0.55];
const TOOL_COLOR: [f32; 3] = [0.25, 0.25, 0.28];

#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    #[error(
        "no graphics adapter that can render and read back depth (install mesa-vulkan-drivers for software Vulkan): {0}"
    )]
    NoAdapter(String),
    #[error("graphics device: {0}")]
    Device(String),
    #[error("{path}: {reason}")]
    Scene { path: String, reason: String },
    #[error("video: {0}")]
    Video(String),
}

/// The adapter in use, recorded with every rendered episode.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AdapterSummary {
    pub name: String,
    pub backend: String,
    pub device_type: String,
    pub driver: String,
}

impl std::fmt::Display for AdapterSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} ({}, {}, {})",
            self.name, self.backend, self.device_type, self.driver
        )
    }
}

/// Which images to read back besides RGB.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Outputs {
    pub depth: bool,
    pub segments: bool,
}

impl Outputs {
    pub const ALL: Outputs = Outputs {
        depth: true,
        segments: true,
    };
    pub const RGB: Outputs = Outputs {
        depth: false,
        segments: false,
    };
}

/// One rendered camera image. Rows run top to bottom.
#[derive(Debug, Clone)]
pub struct Frame {
    pub width: u32,
    pub height: u32,
    /// RGBA, 8 bits per channel.
    pub rgba: Vec<u8>,
    /// Distance (m) from the camera plane along its axis; infinity where nothing was drawn.
    pub depth: Vec<f32>,
    /// Segment ids (see `assay_spec::scene`): 0 background, 1 surface, 2 tool, 3 + i object i.
    pub segments: Vec<u32>,
}

#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
struct Instance {
    model: Mat4,
    color: [f32; 4],
    segment: u32,
    _pad: [u32; 3],
}

#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
struct Globals {
    view_proj: Mat4,
    light_dir: [f32; 4],
    ambient: [f32; 4],
}

const SHADER: &str = r#"
struct Globals { view_proj: mat4x4<f32>, light_dir: vec4<f32>, ambient: vec4<f32> };
@group(0) @binding(0) var<uniform> g: Globals;
struct VIn {
  @location(0) pos: vec3<f32>, @location(1) normal: vec3<f32>,
  @location(2) m0: vec4<f32>, @location(3) m1: vec4<f32>, @location(4) m2: vec4<f32>, @location(5) m3: vec4<f32>,
  @location(6) color: vec4<f32>, @location(7) seg: u32,
};
struct VOut {
  @builtin(position) clip: vec4<f32>,
  @location(0) color: vec4<f32>, @location(1) @interpolate(flat) seg: u32,
};
// The same, for meshes whose faces are flat (boxes, and mesh files, whose vertices are split per
// face): every vertex of a face has the face's colour, so the colour needs no interpolation —
// which a software rasteriser otherwise does per pixel (measured on lavapipe: a quarter more
// frames per CPU-second on the reference scene).
struct VOutFlat {
  @builtin(position) clip: vec4<f32>,
  @location(0) @interpolate(flat) color: vec4<f32>, @location(1) @interpolate(flat) seg: u32,
};
// Diffuse shading per vertex (Gouraud): the fragment stage only writes what it is given, which is
// what makes a software rasteriser fast. Boxes have one normal per face, so they shade exactly as
// per-fragment lighting would; spheres and cylinders are tessellated finely enough not to show it.
fn shade(v: VIn) -> VOut {
  let m = mat4x4<f32>(v.m0, v.m1, v.m2, v.m3);
  let c0 = v.m0.xyz; let c1 = v.m1.xyz; let c2 = v.m2.xyz;
  let n = normalize(c0 * (v.normal.x / dot(c0, c0)) + c1 * (v.normal.y / dot(c1, c1)) + c2 * (v.normal.z / dot(c2, c2)));
  let diffuse = abs(dot(n, normalize(g.light_dir.xyz)));
  let k = g.ambient.x + (1.0 - g.ambient.x) * diffuse;
  var o: VOut;
  o.clip = g.view_proj * (m * vec4<f32>(v.pos, 1.0));
  o.color = vec4<f32>(v.color.rgb * k, 1.0);
  o.seg = v.seg;
  return o;
}
@vertex fn vs_main(v: VIn) -> VOut {
  return shade(v);
}
@vertex fn vs_flat(v: VIn) -> VOutFlat {
  let s = shade(v);
  var o: VOutFlat;
  o.clip = s.clip;
  o.color = s.color;
  o.seg = s.seg;
  return o;
}
struct FOut { @location(0) color: vec4<f32>, @location(1) seg: u32 };
@fragment fn fs_main(i: VOut) -> FOut {
  var o: FOut;
  o.color = i.color;
  o.seg = i.seg;
  return o;
}
@fragment fn fs_rgb(i: VOut) -> @location(0) vec4<f32> {
  return i.color;
}
@fragment fn fs_main_flat(i: VOutFlat) -> FOut {
  var o: FOut;
  o.color = i.color;
  o.seg = i.seg;
  return o;
}
@fragment fn fs_rgb_flat(i: VOutFlat) -> @location(0) vec4<f32> {
  return i.color;
}"#;

struct GpuMesh {
    vertices: wgpu::Buffer,
    indices: wgpu::Buffer,
    count: u32,
}

struct Targets {
    width: u32,
    height: u32,
    color: wgpu::Texture,
    depth: wgpu::Texture,
    segments: wgpu::Texture,
    views: [wgpu::TextureView; 3],
    readback: [wgpu::Buffer; 3],
}

/// One visual part of a URDF object: its mesh, placement and scale in the object's frame, and
/// its own colour when the URDF gives one.
#[derive(Debug, Clone)]
struct UrdfPart {
    mesh: MeshKey,
    pose: assay_spec::urdf::Pose,
    scale: [f32; 3],
    color: Option<[f32; 3]>,
    /// A part of the base link (the URDF's root): drawn in the object's colour where the task
    /// gave one (PyBullet's `changeVisualShape(body, -1, rgbaColor)`).
    base: bool,
}

/// Which unit mesh an instance uses.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
enum MeshKey {
    Box,
    Sphere,
    Cylinder,
    File(String),
}

impl MeshKey {
    /// Whether every vertex of a face has the face's normal (`mesh`: the box, and mesh files,
    /// split per face), so a face has one colour.
    fn flat_faces(&self) -> bool {
        matches!(self, MeshKey::Box | MeshKey::File(_))
    }
}

/// The render pipelines: with segments or colour only, for smooth or flat-faced meshes.
struct Pipelines {
    all: wgpu::RenderPipeline,
    rgb: wgpu::RenderPipeline,
    all_flat: wgpu::RenderPipeline,
    rgb_flat: wgpu::RenderPipeline,
}

/// How many posed URDF objects the renderer keeps before it starts over.
const MAX_URDF_POSES: usize = 512;

pub struct Renderer {
    device: wgpu::Device,
    queue: wgpu::Queue,
    /// Write colour and segments, and colour only (cheaper when segments are not wanted): for
    /// meshes with smooth normals, and for meshes with flat faces (no colour interpolation).
    pipelines: Pipelines,
    /// Instance data of the current frame, reused across frames (grown when needed).
    instance_buffer: Option<wgpu::Buffer>,
    globals: wgpu::Buffer,
    bind_group: wgpu::BindGroup,
    meshes: HashMap<MeshKey, GpuMesh>,
    /// URDF objects by file and joint positions: their visual parts in the object's frame.
    urdfs: HashMap<String, Vec<UrdfPart>>,
    /// Render targets by size, the most recently used first (at most [`KEPT_TARGET_SIZES`]): a
    /// worker alternates between its image size, the policy camera's and the clip size.
    targets: Vec<Targets>,
    adapter: AdapterSummary,
}

/// Render target sizes a renderer keeps.
const KEPT_TARGET_SIZES: usize = 3;

fn padded_row(width: u32) -> u32 {
    (width * 4).div_ceil(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT) * wgpu::COPY_BYTES_PER_ROW_ALIGNMENT
}

impl Renderer {
    /// Opens the best adapter that can render and read depth back: a GPU before a software
    /// rasteriser, Vulkan before GL. `WGPU_BACKEND` (vulkan, gl) narrows the choice.
    pub fn new() -> Result<Self, RenderError> {
        pollster::block_on(Self::new_async())
    }

    async fn new_async() -> Result<Self, RenderError> {
        let backends =
            wgpu::Backends::from_env().unwrap_or(wgpu::Backends::VULKAN | wgpu::Backends::GL);
        let instance = wgpu::Instance::new(wgpu::InstanceDescriptor {
            backends,
            // lavapipe may not claim Vulkan conformance; it is exactly the adapter we want on a CPU.
            flags: wgpu::InstanceFlags::ALLOW_UNDERLYING_NONCOMPLIANT_ADAPTER,
            ..wgpu::InstanceDescriptor::new_without_display_handle()
        });
        let mut adapters: Vec<wgpu::Adapter> = instance
            .enumerate_adapters(backends)
            .await
            .into_iter()
            .filter(|a| {
                a.get_downlevel_capabilities()
                    .flags
                    .contains(wgpu::DownlevelFlags::DEPTH_TEXTURE_AND_BUFFER_COPIES)
            })
            .collect();
        adapters.sort_by_key(|a| {
            let i = a.get_info();
            (
                i.device_type == wgpu::DeviceType::Cpu,
                i.backend != wgpu::Backend::Vulkan,
            )
        });
        let Some(adapter) = adapters.into_iter().next() else {
            return Err(RenderError::NoAdapter(format!("backends {backends:?}")));
        };
        let info = adapter.get_info();
        let summary = AdapterSummary {
            name: info.name.clone(),
            backend: info.backend.to_string(),
            device_type: format!("{:?}", info.device_type),
            driver: format!("{} {}", info.driver, info.driver_info)
                .trim()
                .to_owned(),
        };
        tracing::info!(adapter = %summary, "render adapter");
        let (device, queue) = adapter
            .request_device(&wgpu::DeviceDescriptor {
                label: Some("assay-render"),
                required_features: wgpu::Features::empty(),
                required_limits: wgpu::Limits::downlevel_defaults()
                    .using_resolution(adapter.limits()),
                experimental_features: wgpu::ExperimentalFeatures::disabled(),
                memory_hints: wgpu::MemoryHints::MemoryUsage,
                trace: wgpu::Trace::Off,
            })
            .await
            .map_err(|e| RenderError::Device(e.to_string()))?;
        let shader = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("scene"),
            source: wgpu::ShaderSource::Wgsl(Cow::Borrowed(SHADER)),
        });
        let globals = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("globals"),
            size: size_of::<Globals>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let bgl = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("globals"),
            entries: &[wgpu::BindGroupLayoutEntry {
                binding: 0,
                visibility: wgpu::ShaderStages::VERTEX_FRAGMENT,
                count: None,
                ty: wgpu::BindingType::Buffer {
                    ty: wgpu::BufferBindingType::Uniform,
                    has_dynamic_offset: false,
                    min_binding_size: None,
                },
            }],
        });
        let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("globals"),
            layout: &bgl,
            entries: &[wgpu::BindGroupEntry {
                binding: 0,
                resource: globals.as_entire_binding(),
            }],
        });
        let layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("scene"),
            bind_group_layouts: &[Some(&bgl)],
            immediate_size: 0,
        });
        const VERTEX_ATTRS: [wgpu::VertexAttribute; 2] =
            wgpu::vertex_attr_array![0 => Float32x3, 1 => Float32x3];
        const INSTANCE_ATTRS: [wgpu::VertexAttribute; 6] = wgpu::vertex_attr_array![
            2 => Float32x4, 3 => Float32x4, 4 => Float32x4, 5 => Float32x4, 6 => Float32x4, 7 => Uint32];
        let make_pipeline =
            |vertex: &str, entry: &str, targets: &[Option<wgpu::ColorTargetState>]| {
                device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                    label: Some("scene"),
                    layout: Some(&layout),
                    vertex: wgpu::VertexState {
                        module: &shader,
                        entry_point: Some(vertex),
                        compilation_options: wgpu::PipelineCompilationOptions::default(),
                        buffers: &[
                            Some(wgpu::VertexBufferLayout {
                                array_stride: size_of::<Vertex>() as u64,
                                step_mode: wgpu::VertexStepMode::Vertex,
                                attributes: &VERTEX_ATTRS,
                            }),
                            Some(wgpu::VertexBufferLayout {
                                array_stride: size_of::<Instance>() as u64,
                                step_mode: wgpu::VertexStepMode::Instance,
                                attributes: &INSTANCE_ATTRS,
                            }),
                        ],
                    },
                    primitive: wgpu::PrimitiveState {
                        cull_mode: None,
                        ..Default::default()
                    },
                    depth_stencil: Some(wgpu::DepthStencilState {
                        format: wgpu::TextureFormat::Depth32Float,
                        depth_write_enabled: Some(true),
                        depth_compare: Some(wgpu::CompareFunction::Less),
                        stencil: wgpu::StencilState::default(),
                        bias: wgpu::DepthBiasState::default(),
                    }),
                    multisample: wgpu::MultisampleState::default(),
                    fragment: Some(wgpu::FragmentState {
                        module: &shader,
                        entry_point: Some(entry),
                        compilation_options: wgpu::PipelineCompilationOptions::default(),
                        targets,
                    }),
                    multiview_mask: None,
                    cache: None,
                })
            };
        let color_target = Some(wgpu::ColorTargetState {
            format: wgpu::TextureFormat::Rgba8Unorm,
            blend: None,
            write_mask: wgpu::ColorWrites::ALL,
        });
        let segment_target = Some(wgpu::ColorTargetState {
            format: wgpu::TextureFormat::R32Uint,
            blend: None,
            write_mask: wgpu::ColorWrites::ALL,
        });
        let both = [color_target.clone(), segment_target];
        let color = [color_target];
        let pipelines = Pipelines {
            all: make_pipeline("vs_main", "fs_main", &both),
            rgb: make_pipeline("vs_main", "fs_rgb", &color),
            all_flat: make_pipeline("vs_flat", "fs_main_flat", &both),
            rgb_flat: make_pipeline("vs_flat", "fs_rgb_flat", &color),
        };
        let mut r = Renderer {
            device,
            queue,
            pipelines,
            instance_buffer: None,
            globals,
            bind_group,
            meshes: HashMap::new(),
            urdfs: HashMap::new(),
            targets: Vec::new(),
            adapter: summary,
        };
        r.upload(MeshKey::Box, &mesh::unit_box());
        r.upload(MeshKey::Sphere, &mesh::unit_sphere(16, 24));
        r.upload(MeshKey::Cylinder, &mesh::unit_cylinder(24));
        Ok(r)
    }

    pub fn adapter(&self) -> &AdapterSummary {
        &self.adapter
    }

    fn upload(&mut self, key: MeshKey, m: &MeshData) {
        let vertices = self
            .device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("vertices"),
                contents: bytemuck::cast_slice(&m.vertices),
                usage: wgpu::BufferUsages::VERTEX,
            });
        let indices = self
            .device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("indices"),
                contents: bytemuck::cast_slice(&m.indices),
                usage: wgpu::BufferUsages::INDEX,
            });
        self.meshes.insert(
            key,
            GpuMesh {
                vertices,
                indices,
                count: m.indices.len() as u32,
            },
        );
    }

    /// Makes the targets of `width` × `height` the first of `self.targets`.
    fn targets(&mut self, width: u32, height: u32) {
        if let Some(i) = self
            .targets
            .iter()
            .position(|t| t.width == width && t.height == height)
        {
            self.targets[..=i].rotate_right(1);
        } else {
            let size = wgpu::Extent3d {
                width,
                height,
                depth_or_array_layers: 1,
            };
            let tex = |label: &str, format| {
                self.device.create_texture(&wgpu::TextureDescriptor {
                    label: Some(label),
                    size,
                    mip_level_count: 1,
                    sample_count: 1,
                    dimension: wgpu::TextureDimension::D2,
                    format,
                    usage: wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC,
                    view_formats: &[],
                })
            };
            let buf = |label: &str| {
                self.device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some(label),
                    size: u64::from(padded_row(width)) * u64::from(height),
                    usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                    mapped_at_creation: false,
                })
            };
            let (color, depth, segments) = (
                tex("color", wgpu::TextureFormat::Rgba8Unorm),
                tex("depth", wgpu::TextureFormat::Depth32Float),
                tex("segments", wgpu::TextureFormat::R32Uint),
            );
            let view = |t: &wgpu::Texture| t.create_view(&wgpu::TextureViewDescriptor::default());
            let views = [view(&color), view(&depth), view(&segments)];
            self.targets.insert(
                0,
                Targets {
                    width,
                    height,
                    color,
                    depth,
                    segments,
                    views,
                    readback: [
                        buf("color readback"),
                        buf("depth readback"),
                        buf("segment readback"),
                    ],
                },
            );
            self.targets.truncate(KEPT_TARGET_SIZES);
        }
    }

    /// Reads a URDF object once per joint positions: its visual parts, with their meshes
    /// uploaded. `frame_at` fixes the object's frame (an articulated object's initial joints),
    /// `joints` poses the links.
    fn load_urdf(
        &mut self,
        i: usize,
        path: &str,
        fill: &std::collections::BTreeMap<String, String>,
        frame_at: &std::collections::BTreeMap<String, f64>,
        joints: &std::collections::BTreeMap<String, f64>,
    ) -> Result<String, RenderError> {
        use assay_spec::urdf::Geometry;
        let key = format!("{path}|{fill:?}|{frame_at:?}|{joints:?}");
        if self.urdfs.contains_key(&key) {
            return Ok(key);
        }
        // An articulated object takes a new pose every frame: bound the cache.
        if self.urdfs.len() >= MAX_URDF_POSES {
            self.urdfs.clear();
            self.meshes
                .retain(|k, _| !matches!(k, MeshKey::File(f) if f.contains('|')));
        }
        let a =
            assay_spec::urdf::assemble_filled(std::path::Path::new(path), fill, frame_at, joints)
                .map_err(|reason| RenderError::Scene {
                path: format!("scene.objects[{i}].shape.urdf"),
                reason,
            })?;
        let mut parts = Vec::new();
        for (k, (part, mesh)) in a.visuals.iter().enumerate() {
            let (key, scale) = match &part.geometry {
                Geometry::Box { size } => (MeshKey::Box, size.map(|x| x as f32 / 2.0)),
                Geometry::Sphere { radius } => (MeshKey::Sphere, [*radius as f32; 3]),
                Geometry::Cylinder { radius, length } => {
                    let r = *radius as f32;
                    (MeshKey::Cylinder, [r, r, *length as f32 / 2.0])
                }
                Geometry::Mesh { scale, .. } => {
                    let mesh_key = MeshKey::File(format!("{key}#{k}"));
                    if let Some(m) = mesh {
                        self.upload(
                            mesh_key.clone(),
                            &mesh::from_triangles(&m.vertices, &m.triangles, 1.0),
                        );
                    }
                    (mesh_key, scale.map(|x| x as f32))
                }
            };
            parts.push(UrdfPart {
                mesh: key,
                pose: part.pose,
                scale,
                color: part.color.map(|c| [c[0], c[1], c[2]]),
                base: part.link == a.urdf.root(),
            });
        }
        self.urdfs.insert(key.clone(), parts);
        Ok(key)
    }

    /// Instances per mesh for one snapshot.
    fn instances(
        &mut self,
        scene: &SceneSnapshot,
    ) -> Result<Vec<(MeshKey, Vec<Instance>)>, RenderError> {
        let mut urdf_keys = HashMap::new();
        for (i, o) in scene.objects.iter().enumerate() {
            if let Shape::Urdf {
                path,
                joints,
                articulated,
                fill,
            } = &o.shape
            {
                // A snapshot of an articulated object carries its joints at that moment.
                let posed = if *articulated && !o.joints.is_empty() {
                    &o.joints
                } else {
                    joints
                };
                // Its frame is fixed by its links at their default positions.
                let none = std::collections::BTreeMap::new();
                let frame_at = if *articulated { &none } else { joints };
                urdf_keys.insert(i, self.load_urdf(i, path, fill, frame_at, posed)?);
            }
        }
        let mut by_mesh: Vec<(MeshKey, Vec<Instance>)> = Vec::new();
        let mut push = |key: MeshKey, model: Mat4, color: [f32; 3], segment: u32| {
            let inst = Instance {
                model,
                color: [color[0], color[1], color[2], 1.0],
                segment,
                _pad: [0; 3],
            };
            match by_mesh.iter_mut().find(|(k, _)| *k == key) {
                Some((_, v)) => v.push(inst),
                None => by_mesh.push((key, vec![inst])),
            }
        };
        let identity = [0.0, 0.0, 0.0, 1.0];
        match scene.surface {
            Surface::Table => {
                let [hx, hy] = TABLE_HALF_EXTENTS.map(|x| x as f32);
                let c = TABLE_CENTER.map(|x| x as f32);
                push(
                    MeshKey::Box,
                    trs([c[0], c[1], -0.05], identity, [hx, hy, 0.05]),
                    TABLE_COLOR,
                    SEGMENT_SURFACE,
                );
            }
            Surface::Ground => push(
                MeshKey::Box,
                trs([0.5, 0.0, -0.05], identity, [5.0, 5.0, 0.05]),
                GROUND_COLOR,
                SEGMENT_SURFACE,
            ),
        }
        if let Some(t) = scene.tool {
            push(
                MeshKey::Box,
                trs(
                    t,
                    scene.tool_rotation.unwrap_or(identity),
                    TOOL_HALF_EXTENTS.map(|x| x as f32),
                ),
                TOOL_COLOR,
                SEGMENT_TOOL,
            );
        }
        for f in scene.fingers.iter().chain(&scene.arm) {
            push(
                MeshKey::Box,
                trs(f.position, f.rotation, f.half_extents),
                TOOL_COLOR,
                SEGMENT_TOOL,
            );
        }
        let mut files = Vec::new();
        for (i, o) in scene.objects.iter().enumerate() {
            let seg = FIRST_OBJECT_SEGMENT + i as u32;
            let (p, q) = (o.position, o.rotation);
            match &o.shape {
                Shape::Box { half_extents } => push(
                    MeshKey::Box,
                    trs(p, q, half_extents.map(|x| x as f32)),
                    o.color,
                    seg,
                ),
                Shape::Sphere { radius } => push(
                    MeshKey::Sphere,
                    trs(p, q, [*radius as f32; 3]),
                    o.color,
                    seg,
                ),
                Shape::Cylinder {
                    radius,
                    half_height,
                } => {
                    let (r, h) = (*radius as f32, *half_height as f32);
                    push(MeshKey::Cylinder, trs(p, q, [r, r, h]), o.color, seg);
                }
                Shape::Container {
                    inner_half_extents,
                    wall,
                } => {
                    let [ix, iy, iz] = inner_half_extents.map(|x| x as f32);
                    let w = *wall as f32;
                    let big = iz + w / 2.0;
                    let wall_z = -big + w + iz;
                    let mut parts = vec![([0.0, 0.0, -big + w / 2.0], [ix + w, iy + w, w / 2.0])];
                    for s in [-1.0f32, 1.0] {
                        parts.push(([s * (ix + w / 2.0), 0.0, wall_z], [w / 2.0, iy + w, iz]));
                        parts.push(([0.0, s * (iy + w / 2.0), wall_z], [ix, w / 2.0, iz]));
                    }
                    for (offset, half) in parts {
                        let d = rotate(q, offset);
                        push(
                            MeshKey::Box,
                            trs([p[0] + d[0], p[1] + d[1], p[2] + d[2]], q, half),
                            o.color,
                            seg,
                        );
                    }
                }
                Shape::Mesh { path, scale, .. } => {
                    let key = MeshKey::File(format!("{path}@{scale}"));
                    files.push((i, path.clone(), *scale as f32, key.clone()));
                    push(key, trs(p, q, [1.0; 3]), o.color, seg);
                }
                Shape::Urdf { .. } => {
                    let object = assay_spec::urdf::Pose {
                        translation: p.map(f64::from),
                        rotation: q.map(f64::from),
                    };
                    for part in &self.urdfs[&urdf_keys[&i]] {
                        let world = object.compose(&part.pose);
                        push(
                            part.mesh.clone(),
                            trs(
                                world.translation.map(|x| x as f32),
                                world.rotation.map(|x| x as f32),
                                part.scale,
                            ),
                            match part.color {
                                Some(own) if !(part.base && o.color_given) => own,
                                _ => o.color,
                            },
                            seg,
                        );
                    }
                }
            }
        }
        for (i, path, scale, key) in files {
            if self.meshes.contains_key(&key) {
                continue;
            }
            let fail = |reason: String| RenderError::Scene {
                path: format!("scene.objects[{i}].shape.mesh.path"),
                reason,
            };
            let text = assay_spec::assets::read_to_string(std::path::Path::new(&path))
                .map_err(|e| fail(format!("cannot read {path}: {e}")))?;
            let m =
                assay_spec::scene::parse_obj(&text).map_err(|e| fail(format!("{path}: {e}")))?;
            self.upload(key, &mesh::from_triangles(&m.vertices, &m.triangles, scale));
        }
        Ok(by_mesh)
    }

    /// Renders `scene` from `camera`: RGB, depth and segments.
    pub fn render(&mut self, scene: &SceneSnapshot, camera: &Camera) -> Result<Frame, RenderError> {
        self.render_with(scene, camera, Outputs::ALL)
    }

    /// Renders `scene` from `camera`, reading back only the `outputs` asked for (the others are
    /// left empty in the frame). All of them come from the same single render pass.
    pub fn render_with(
        &mut self,
        scene: &SceneSnapshot,
        camera: &Camera,
        outputs: Outputs,
    ) -> Result<Frame, RenderError> {
        self.render_impl(scene, camera, outputs, None)
    }

    /// Renders RGBA straight into `dst` (for example a frame-bus sample in shared memory), with
    /// no intermediate buffer: the GPU readback is copied row by row into place. `dst` must hold
    /// exactly width × height × 4 bytes.
    pub fn render_rgba_into(
        &mut self,
        scene: &SceneSnapshot,
        camera: &Camera,
        dst: &mut [u8],
    ) -> Result<(), RenderError> {
        self.render_into(scene, camera, Outputs::RGB, dst)
            .map(|_| ())
    }

    /// [`Renderer::render_with`], with RGBA written straight into `dst` as
    /// [`Renderer::render_rgba_into`] does; the frame returned holds the other `outputs` (its
    /// `rgba` is empty).
    pub fn render_into(
        &mut self,
        scene: &SceneSnapshot,
        camera: &Camera,
        outputs: Outputs,
        dst: &mut [u8],
    ) -> Result<Frame, RenderError> {
        let expected = camera.width.max(1) as usize * camera.height.max(1) as usize * 4;
        if dst.len() != expected {
            return Err(RenderError::Device(format!(
                "destination holds {} bytes, the frame needs {expected}",
                dst.len()
            )));
        }
        self.render_impl(scene, camera, outputs, Some(dst))
    }

    fn render_impl(
        &mut self,
        scene: &SceneSnapshot,
        camera: &Camera,
        outputs: Outputs,
        rgba_into: Option<&mut [u8]>,
    ) -> Result<Frame, RenderError> {
        let (w, h) = (camera.width.max(1), camera.height.max(1));
        let (eye, target, up) = if camera.name == EE_CAMERA {
            let t = scene.tool.ok_or_else(|| RenderError::Scene {
                path: "cameras".into(),
                reason: "the end-effector camera needs the tool in the snapshot".into(),
            })?;
            // Along the tool's axis from below its centre, the image's top towards its x axis.
            let r = scene.tool_rotation.unwrap_or([0.0, 0.0, 0.0, 1.0]);
            let at = |v: [f32; 3]| {
                let d = math::rotate(r, v);
                [t[0] + d[0], t[1] + d[1], t[2] + d[2]]
            };
            let up = scene
                .tool_rotation
                .map(|r| math::rotate(r, [1.0, 0.0, 0.0]));
            (at([0.0, 0.0, -0.06]), at([0.0, 0.0, -1.0]), up)
        } else {
            (
                camera.eye.map(|x| x as f32),
                camera.target.map(|x| x as f32),
                camera.up.map(|u| u.map(|x| x as f32)),
            )
        };
        let view_proj = mul(
            &perspective(
                (camera.fovy_deg as f32).to_radians(),
                w as f32 / h as f32,
                ZNEAR,
                ZFAR,
            ),
            &math::look_at(eye, target, up),
        );
        let globals = Globals {
            view_proj,
            light_dir: [0.35, 0.25, 1.0, 0.0],
            ambient: [0.35, 0.0, 0.0, 0.0],
        };
        self.queue
            .write_buffer(&self.globals, 0, bytemuck::bytes_of(&globals));
        let instances = self.instances(scene)?;
        self.targets(w, h);
        // All instances in one buffer, reused across frames: (mesh, byte range, count).
        let mut data: Vec<Instance> = Vec::new();
        let mut groups: Vec<(MeshKey, u64, u64, u32)> = Vec::new();
        for (key, v) in instances {
            let start = (data.len() * size_of::<Instance>()) as u64;
            data.extend_from_slice(&v);
            groups.push((
                key,
                start,
                (data.len() * size_of::<Instance>()) as u64,
                v.len() as u32,
            ));
        }
        let bytes: &[u8] = bytemuck::cast_slice(&data);
        if self
            .instance_buffer
            .as_ref()
            .is_none_or(|b| b.size() < bytes.len() as u64)
        {
            self.instance_buffer = Some(self.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("instances"),
                size: (bytes.len() as u64).next_power_of_two().max(4096),
                usage: wgpu::BufferUsages::VERTEX | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            }));
        }
        let instance_buffer = self
            .instance_buffer
            .as_ref()
            .expect("instance buffer exists");
        self.queue.write_buffer(instance_buffer, 0, bytes);
        let t = &self.targets[0];
        let [color_view, depth_view, seg_view] = &t.views;
        let mut enc = self
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("frame"),
            });
        {
            let clear = |c: wgpu::Color| wgpu::Operations {
                load: wgpu::LoadOp::Clear(c),
                store: wgpu::StoreOp::Store,
            };
            let [r, g, b] = BACKGROUND;
            let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("scene"),
                color_attachments: &[
                    Some(wgpu::RenderPassColorAttachment {
                        view: color_view,
                        depth_slice: None,
                        resolve_target: None,
                        ops: clear(wgpu::Color { r, g, b, a: 1.0 }),
                    }),
                    outputs.segments.then_some(wgpu::RenderPassColorAttachment {
                        view: seg_view,
                        depth_slice: None,
                        resolve_target: None,
                        ops: clear(wgpu::Color::TRANSPARENT),
                    }),
                ][..if outputs.segments { 2 } else { 1 }],
                depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                    view: depth_view,
                    depth_ops: Some(wgpu::Operations {
                        load: wgpu::LoadOp::Clear(1.0),
                        // Depth is only kept when it is read back.
                        store: if outputs.depth {
                            wgpu::StoreOp::Store
                        } else {
                            wgpu::StoreOp::Discard
                        },
                    }),
                    stencil_ops: None,
                }),
                timestamp_writes: None,
                occlusion_query_set: None,
                multiview_mask: None,
            });
            pass.set_bind_group(0, &self.bind_group, &[]);
            let mut current = None;
            for (key, start, end, n) in &groups {
                let flat = key.flat_faces();
                if current != Some(flat) {
                    let p = &self.pipelines;
                    pass.set_pipeline(match (outputs.segments, flat) {
                        (true, false) => &p.all,
                        (false, false) => &p.rgb,
                        (true, true) => &p.all_flat,
                        (false, true) => &p.rgb_flat,
                    });
                    current = Some(flat);
                }
                let m = &self.meshes[key];
                pass.set_vertex_buffer(0, m.vertices.slice(..));
                pass.set_vertex_buffer(1, instance_buffer.slice(*start..*end));
                pass.set_index_buffer(m.indices.slice(..), wgpu::IndexFormat::Uint32);
                pass.draw_indexed(0..m.count, 0, 0..*n);
            }
        }
        let row = padded_row(w);
        let size = wgpu::Extent3d {
            width: w,
            height: h,
            depth_or_array_layers: 1,
        };
        let wanted = [true, outputs.depth, outputs.segments];
        let copies = [
            (&t.color, wgpu::TextureAspect::All, &t.readback[0]),
            (&t.depth, wgpu::TextureAspect::DepthOnly, &t.readback[1]),
            (&t.segments, wgpu::TextureAspect::All, &t.readback[2]),
        ];
        for (tex, aspect, buf) in copies
            .into_iter()
            .zip(wanted)
            .filter(|(_, w)| *w)
            .map(|(c, _)| c)
        {
            enc.copy_texture_to_buffer(
                wgpu::TexelCopyTextureInfo {
                    texture: tex,
                    mip_level: 0,
                    origin: wgpu::Origin3d::ZERO,
                    aspect,
                },
                wgpu::TexelCopyBufferInfo {
                    buffer: buf,
                    layout: wgpu::TexelCopyBufferLayout {
                        offset: 0,
                        bytes_per_row: Some(row),
                        rows_per_image: Some(h),
                    },
                },
                size,
            );
        }
        let index = self.queue.submit([enc.finish()]);
        let (tx, rx) = std::sync::mpsc::channel();
        for buf in t
            .readback
            .iter()
            .zip(wanted)
            .filter(|(_, w)| *w)
            .map(|(b, _)| b)
        {
            let tx = tx.clone();
            buf.map_async(wgpu::MapMode::Read, .., move |r| {
                let _ = tx.send(r);
            });
        }
        self.device
            .poll(wgpu::PollType::Wait {
                submission_index: Some(index),
                timeout: None,
            })
            .map_err(|e| RenderError::Device(e.to_string()))?;
        for _ in 0..wanted.iter().filter(|w| **w).count() {
            rx.recv()
                .map_err(|e| RenderError::Device(e.to_string()))?
                .map_err(|e| RenderError::Device(e.to_string()))?;
        }
        let read = |buf: &wgpu::Buffer| -> Result<Vec<u8>, RenderError> {
            let tight = (w * 4) as usize;
            let mut out = Vec::with_capacity(tight * h as usize);
            {
                let view = buf
                    .get_mapped_range(..)
                    .map_err(|e| RenderError::Device(e.to_string()))?;
                for y in 0..h as usize {
                    out.extend_from_slice(&view[y * row as usize..][..tight]);
                }
            }
            buf.unmap();
            Ok(out)
        };
        let rgba = match rgba_into {
            Some(dst) => {
                let tight = (w * 4) as usize;
                {
                    let view = t.readback[0]
                        .get_mapped_range(..)
                        .map_err(|e| RenderError::Device(e.to_string()))?;
                    for (y, out) in dst.chunks_exact_mut(tight).enumerate() {
                        out.copy_from_slice(&view[y * row as usize..][..tight]);
                    }
                }
                t.readback[0].unmap();
                Vec::new()
            }
            None => read(&t.readback[0])?,
        };
        let depth = if !outputs.depth {
            Vec::new()
        } else {
            read(&t.readback[1])?
                .chunks_exact(4)
                .map(|b| {
                    let d = f32::from_le_bytes([b[0], b[1], b[2], b[3]]);
                    if d >= 1.0 {
                        f32::INFINITY
                    } else {
                        ZNEAR * ZFAR / (ZFAR - d * (ZFAR - ZNEAR))
                    }
                })
                .collect()
        };
        let segments = if !outputs.segments {
            Vec::new()
        } else {
            read(&t.readback[2])?
                .chunks_exact(4)
                .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                .collect()
        };
        Ok(Frame {
            width: w,
            height: h,
            rgba,
            depth,
            segments,
        })
    }
}
