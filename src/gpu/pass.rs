//! Set-up shared by the bundle passes: bind-group layouts of buffers bound in order, and the
//! attachment-less raster the analysis and linked-list passes draw with (their fragment
//! stages write storage buffers only).

/// Colour target the bundle rasters need (wgpu wants an attachment; nothing is written to it).
pub const RASTER_TARGET_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::R8Unorm;

/// Storage read by the shader.
pub const READ: wgpu::BufferBindingType = wgpu::BufferBindingType::Storage { read_only: true };
/// Storage written by the shader.
pub const WRITE: wgpu::BufferBindingType = wgpu::BufferBindingType::Storage { read_only: false };
/// A uniform block.
pub const UNIFORM: wgpu::BufferBindingType = wgpu::BufferBindingType::Uniform;

/// A bind-group layout of whole buffers, binding `i` being `buffers[i]` (stages, type).
pub fn buffer_layout(
    device: &wgpu::Device,
    label: &str,
    buffers: &[(wgpu::ShaderStages, wgpu::BufferBindingType)],
) -> wgpu::BindGroupLayout {
    let entries: Vec<wgpu::BindGroupLayoutEntry> = buffers
        .iter()
        .enumerate()
        .map(|(i, &(visibility, ty))| wgpu::BindGroupLayoutEntry {
            binding: i as u32,
            visibility,
            ty: wgpu::BindingType::Buffer { ty, has_dynamic_offset: false, min_binding_size: None },
            count: None,
        })
        .collect();
    device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor { label: Some(label), entries: &entries })
}

/// A pipeline layout of one bind group.
pub fn single_group(device: &wgpu::Device, label: &str, layout: &wgpu::BindGroupLayout) -> wgpu::PipelineLayout {
    device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
        label: Some(label),
        bind_group_layouts: &[Some(layout)],
        immediate_size: 0,
    })
}

/// The bundle raster of `module` (`vs_main` pulls the triangles from storage, no vertex
/// buffers; `fs_main` writes storage): both faces, into a [`RASTER_TARGET_FORMAT`] target it
/// never writes.
pub fn bundle_raster(
    device: &wgpu::Device,
    label: &str,
    layout: &wgpu::PipelineLayout,
    module: &wgpu::ShaderModule,
) -> wgpu::RenderPipeline {
    device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
        label: Some(label),
        layout: Some(layout),
        vertex: wgpu::VertexState {
            module,
            entry_point: Some("vs_main"),
            compilation_options: Default::default(),
            buffers: &[],
        },
        primitive: wgpu::PrimitiveState {
            topology: wgpu::PrimitiveTopology::TriangleList,
            front_face: wgpu::FrontFace::Ccw,
            cull_mode: None,
            ..Default::default()
        },
        depth_stencil: None,
        multisample: Default::default(),
        fragment: Some(wgpu::FragmentState {
            module,
            entry_point: Some("fs_main"),
            compilation_options: Default::default(),
            targets: &[Some(wgpu::ColorTargetState {
                format: RASTER_TARGET_FORMAT,
                blend: None,
                write_mask: wgpu::ColorWrites::empty(),
            })],
        }),
        multiview_mask: None,
        cache: None,
    })
}
