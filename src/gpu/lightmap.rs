//! The shown light map's GPU mirror: pages in a pool texture, page tables, cell LODs.
//!
//! A page holds 16×16 pixels of one LOD of one layer (rgba32float: E and validity). Each
//! page-table entry (one per page position of each layer's LODs, layer by layer) names the
//! pool slot holding that page, or `NO_PAGE`; the cell LODs are one array per layer. [`LightmapGpu::sync`] compares a new snapshot with the pages it holds by page
//! id: a page whose id changed is written over its own slot, a new page takes a free slot,
//! a vanished one frees its slot; only those pages, the changed table entries and the
//! changed cell LODs are uploaded, never the whole map. The pool grows by doubling, copying
//! the old pool on the GPU (no upload), up to the most pages the device's largest texture
//! holds (or [`LightmapGpu::set_page_cap`]'s cap). Beyond that the mirror never fails: the
//! levels are synced coarsest first, and a page that finds no slot takes one from a page of
//! a finer LOD or, if there is none, is left out. A page left out reads as unpublished, so
//! the sampling function falls back to the coarser level there: the picture shows a coarser
//! LOD where the map outgrew the GPU (the runtime's page limit keeps it from doing so).

use std::sync::Arc;

use bytemuck::cast_slice;

use super::GpuError;
use super::device::GpuContext;
use super::layout::{LightmapParams, LodLevel, MAX_LODS};
use crate::runtime::shown::{Layer, PAGE_SIDE, Page, ShownLightmap};

/// Page-table entry of a page position that holds no page.
pub const NO_PAGE: u32 = u32::MAX;
const TEXEL_BYTES: u32 = 16;
const PAGE_BYTES: u64 = (PAGE_SIDE * PAGE_SIDE * TEXEL_BYTES) as u64;
/// Format of the page pool (E and validity per pixel).
pub const POOL_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba32Float;

/// What one [`LightmapGpu::sync`] uploaded.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SyncReport {
    pub pages_uploaded: u64,
    pub table_entries_uploaded: u64,
    pub cells_uploaded: u64,
    /// All bytes written to GPU buffers and textures (pages, table entries, cell LODs, params).
    pub bytes_uploaded: u64,
    /// Whether the map's shape changed (grid, atlas size, LOD count) and everything was rebuilt.
    pub rebuilt: bool,
    /// Pages of the map left out of the pool (full): their level falls back to a coarser one.
    pub pages_left_out: u64,
    /// Resident pages given up for pages of coarser levels (the pool full).
    pub pages_given_up: u64,
}

impl SyncReport {
    fn add(&mut self, other: SyncReport) {
        self.pages_uploaded += other.pages_uploaded;
        self.table_entries_uploaded += other.table_entries_uploaded;
        self.cells_uploaded += other.cells_uploaded;
        self.bytes_uploaded += other.bytes_uploaded;
        self.rebuilt |= other.rebuilt;
        self.pages_left_out += other.pages_left_out;
        self.pages_given_up += other.pages_given_up;
    }
}

/// Bind group layout of group 1 (lightmap.inc.wgsl), for every pass that samples the map.
pub fn bind_group_layout(device: &wgpu::Device) -> wgpu::BindGroupLayout {
    let visibility = wgpu::ShaderStages::FRAGMENT | wgpu::ShaderStages::COMPUTE;
    let storage = |binding| wgpu::BindGroupLayoutEntry {
        binding,
        visibility,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Storage { read_only: true },
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    };
    device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
        label: Some("lightmap"),
        entries: &[
            wgpu::BindGroupLayoutEntry {
                binding: 0,
                visibility,
                ty: wgpu::BindingType::Buffer {
                    ty: wgpu::BufferBindingType::Uniform,
                    has_dynamic_offset: false,
                    min_binding_size: None,
                },
                count: None,
            },
            storage(1),
            storage(2),
            wgpu::BindGroupLayoutEntry {
                binding: 3,
                visibility,
                ty: wgpu::BindingType::Texture {
                    sample_type: wgpu::TextureSampleType::Float { filterable: false },
                    view_dimension: wgpu::TextureViewDimension::D2,
                    multisampled: false,
                },
                count: None,
            },
        ],
    })
}

/// The shape of a shown map: what must match for a partial update.
#[derive(Clone, Debug, PartialEq)]
struct Shape {
    grid: crate::grid::Grid,
    atlas: (u32, u32),
    levels: Vec<(u32, u32)>,
}

impl Shape {
    fn of(shown: &ShownLightmap) -> Shape {
        Shape {
            grid: shown.grid,
            atlas: (shown.atlas_width, shown.atlas_height),
            levels: shown.layers[0].levels.iter().map(|l| (l.pages_x, l.pages_y)).collect(),
        }
    }
}

pub struct LightmapGpu {
    shape: Shape,
    params: LightmapParams,
    params_buffer: wgpu::Buffer,
    cell_lod_buffer: wgpu::Buffer,
    page_table_buffer: wgpu::Buffer,
    pool: wgpu::Texture,
    pool_columns: u32,
    pool_rows: u32,
    bind_group: wgpu::BindGroup,
    /// Per page-table entry (all LODs, flat): the page id held and its slot.
    resident: Vec<Option<(u64, u32)>>,
    cell_lod: Vec<u8>,
    free_slots: Vec<u32>,
    slots_used: u32,
    /// Most pages the pool may hold.
    page_cap: u32,
    /// Per LOD: pages of either layer resident (the finest give way first when the pool is full).
    resident_per_lod: Vec<u32>,
    /// Everything uploaded since creation.
    pub total: SyncReport,
}

/// Most columns of pages in the pool (its width: 4096 pixels).
const POOL_COLUMNS: u32 = 256;

/// Most pages a pool on `device` holds: as many page slots as its largest 2D texture has, in
/// the pool's at most [`POOL_COLUMNS`] columns (1 GiB of rgba32f on a 16384² device).
pub fn device_page_cap(device: &wgpu::Device) -> u32 {
    let max_side = device.limits().max_texture_dimension_2d;
    let columns = (max_side / PAGE_SIDE).clamp(1, POOL_COLUMNS);
    columns * (max_side / PAGE_SIDE).max(1)
}

impl LightmapGpu {
    /// Uploads `shown` whole (the first upload).
    pub fn new(
        gpu: &GpuContext,
        layout: &wgpu::BindGroupLayout,
        shown: &ShownLightmap,
    ) -> Result<LightmapGpu, GpuError> {
        LightmapGpu::with_page_cap(gpu, layout, shown, u32::MAX)
    }

    /// [`LightmapGpu::new`] with the pool capped at `page_cap` pages (see
    /// [`LightmapGpu::set_page_cap`]).
    pub fn with_page_cap(
        gpu: &GpuContext,
        layout: &wgpu::BindGroupLayout,
        shown: &ShownLightmap,
        page_cap: u32,
    ) -> Result<LightmapGpu, GpuError> {
        let lods = shown.lods() as usize;
        if lods > MAX_LODS || lods == 0 {
            return Err(GpuError::Lightmap(format!("{lods} LODs (the GPU mirror holds 1 to {MAX_LODS})")));
        }
        let device = &gpu.device;
        let shape = Shape::of(shown);
        let mut levels = [LodLevel::default(); 2 * MAX_LODS];
        let mut offset = 0u32;
        for (layer, pages) in shown.layers.iter().enumerate() {
            for (k, l) in pages.levels.iter().enumerate() {
                levels[layer * MAX_LODS + k] =
                    LodLevel { pages_x: l.pages_x, pages_y: l.pages_y, table_offset: offset, _pad: 0 };
                offset += l.pages_x * l.pages_y;
            }
        }
        let cells = shown.grid.len();
        let table_len = offset as usize;
        let max_side = device.limits().max_texture_dimension_2d;
        let pool_columns = (max_side / PAGE_SIDE).clamp(1, POOL_COLUMNS);
        let params = LightmapParams {
            grid_origin: shown.grid.origin.to_array(),
            cell_size: shown.grid.cell_size,
            grid_dims: shown.grid.dims,
            lod_count: lods as u32,
            atlas_size: [shown.atlas_width, shown.atlas_height],
            blend_band: shown.blend_band,
            pool_columns,
            layer_count: 1,
            cell_count: cells as u32,
            _pad0: 0,
            _pad1: 0,
            levels,
        };
        let buffer = |label, size: u64, usage| {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: size.max(4),
                usage: usage | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            })
        };
        let params_buffer = buffer("lightmap params", size_of::<LightmapParams>() as u64, wgpu::BufferUsages::UNIFORM);
        let cell_lod_buffer = buffer("cell lods", 4 * 2 * cells as u64, wgpu::BufferUsages::STORAGE);
        let page_table_buffer = buffer("page table", 4 * table_len as u64, wgpu::BufferUsages::STORAGE);
        let page_cap = device_page_cap(device).min(page_cap.max(1));
        let pages = (shown.layers.iter().map(|l| l.live_pages()).sum::<usize>() as u32).min(page_cap);
        let pool_rows =
            pages.div_ceil(pool_columns).max(1).next_power_of_two().min(page_cap.div_ceil(pool_columns)).max(1);
        let pool = create_pool(device, pool_columns, pool_rows)?;
        let bind_group = create_bind_group(device, layout, &params_buffer, &cell_lod_buffer, &page_table_buffer, &pool);
        let mut mirror = LightmapGpu {
            shape,
            params,
            params_buffer,
            cell_lod_buffer,
            page_table_buffer,
            pool,
            pool_columns,
            pool_rows,
            bind_group,
            resident: vec![None; table_len],
            cell_lod: vec![u8::MAX; 2 * cells],
            free_slots: Vec::new(),
            slots_used: 0,
            page_cap,
            resident_per_lod: vec![0; lods],
            total: SyncReport::default(),
        };
        gpu.queue.write_buffer(&mirror.params_buffer, 0, bytemuck::bytes_of(&mirror.params));
        gpu.queue.write_buffer(&mirror.page_table_buffer, 0, cast_slice(&vec![NO_PAGE; table_len.max(1)]));
        let mut report = SyncReport {
            bytes_uploaded: (size_of::<LightmapParams>() + 4 * table_len.max(1)) as u64,
            rebuilt: true,
            ..SyncReport::default()
        };
        report.add(mirror.update(gpu, layout, shown)?);
        mirror.total = report;
        Ok(mirror)
    }

    /// Brings the mirror to `shown`, uploading only what changed. A snapshot of another
    /// shape (after a reload) rebuilds the mirror.
    pub fn sync(
        &mut self,
        gpu: &GpuContext,
        layout: &wgpu::BindGroupLayout,
        shown: &ShownLightmap,
    ) -> Result<SyncReport, GpuError> {
        if Shape::of(shown) != self.shape {
            let total = self.total;
            *self = LightmapGpu::with_page_cap(gpu, layout, shown, self.page_cap)?;
            let report = self.total;
            self.total.add(total);
            return Ok(report);
        }
        let report = self.update(gpu, layout, shown)?;
        self.total.add(report);
        Ok(report)
    }

    fn update(
        &mut self,
        gpu: &GpuContext,
        layout: &wgpu::BindGroupLayout,
        shown: &ShownLightmap,
    ) -> Result<SyncReport, GpuError> {
        let mut report = SyncReport::default();
        // Pages: compare ids entry by entry, the coarsest level of both layers first, so that
        // a full pool keeps the coarse levels (see the module docs).
        let mut changed_entries = Vec::new();
        let mut uploads: Vec<(u32, Arc<Page>)> = Vec::new();
        let lods = self.resident_per_lod.len();
        for lod in 0..lods {
            for (layer, pages) in shown.layers.iter().enumerate() {
                let level = &pages.levels[lod];
                let offset = self.params.levels[layer * MAX_LODS + lod].table_offset as usize;
                for (i, page) in level.rows.iter().flat_map(|row| row.iter()).enumerate() {
                    let entry = offset + i;
                    match (self.resident[entry], page) {
                        (Some((id, _)), Some(p)) if id == p.id => {}
                        (Some((_, slot)), Some(p)) => {
                            self.resident[entry] = Some((p.id, slot));
                            uploads.push((slot, p.clone()));
                        }
                        (None, Some(p)) => {
                            match self.allocate_slot(gpu, layout, lod, &mut changed_entries, &mut report)? {
                                Some(slot) => {
                                    self.resident[entry] = Some((p.id, slot));
                                    self.resident_per_lod[lod] += 1;
                                    uploads.push((slot, p.clone()));
                                    changed_entries.push(entry);
                                }
                                None => report.pages_left_out += 1,
                            }
                        }
                        (Some((_, slot)), None) => {
                            self.free_slots.push(slot);
                            self.resident[entry] = None;
                            self.resident_per_lod[lod] -= 1;
                            changed_entries.push(entry);
                        }
                        (None, None) => {}
                    }
                }
            }
        }
        // A slot is given up only by a page of a finer LOD than the one taking it, which the
        // loop reaches later: no queued upload loses its slot. Entries were visited level by
        // level; the writes want them ascending.
        changed_entries.sort_unstable();
        changed_entries.dedup();
        for (slot, page) in &uploads {
            if page.texels.len() != (PAGE_SIDE * PAGE_SIDE) as usize {
                return Err(GpuError::Lightmap(format!(
                    "page {} has {} texels, not {PAGE_SIDE}×{PAGE_SIDE}",
                    page.id,
                    page.texels.len()
                )));
            }
            let (col, row) = (slot % self.pool_columns, slot / self.pool_columns);
            gpu.queue.write_texture(
                wgpu::TexelCopyTextureInfo {
                    texture: &self.pool,
                    mip_level: 0,
                    origin: wgpu::Origin3d { x: col * PAGE_SIDE, y: row * PAGE_SIDE, z: 0 },
                    aspect: wgpu::TextureAspect::All,
                },
                cast_slice(&page.texels[..]),
                wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(PAGE_SIDE * TEXEL_BYTES),
                    rows_per_image: Some(PAGE_SIDE),
                },
                wgpu::Extent3d { width: PAGE_SIDE, height: PAGE_SIDE, depth_or_array_layers: 1 },
            );
            report.pages_uploaded += 1;
            report.bytes_uploaded += PAGE_BYTES;
        }
        // Table entries and cell LODs: contiguous runs of changes, one write each.
        let resident = &self.resident;
        report.bytes_uploaded += write_runs(gpu, &self.page_table_buffer, &changed_entries, |i| {
            resident[i].map_or(NO_PAGE, |(_, slot)| slot)
        });
        report.table_entries_uploaded = changed_entries.len() as u64;
        // Cell LODs, layer after layer.
        let lods: Vec<u8> = shown.layers.iter().flat_map(|l| l.cell_lod.iter().copied()).collect();
        let changed_cells: Vec<usize> = (0..lods.len()).filter(|&c| self.cell_lod[c] != lods[c]).collect();
        report.bytes_uploaded += write_runs(gpu, &self.cell_lod_buffer, &changed_cells, |c| lods[c] as u32);
        report.cells_uploaded = changed_cells.len() as u64;
        self.cell_lod.copy_from_slice(&lods);
        // The punctual layer is sampled once something is published in it.
        let layer_count = if shown.layers[1].used { 2 } else { 1 };
        if layer_count != self.params.layer_count {
            self.params.layer_count = layer_count;
            gpu.queue.write_buffer(&self.params_buffer, 0, bytemuck::bytes_of(&self.params));
            report.bytes_uploaded += size_of::<LightmapParams>() as u64;
        }
        Ok(report)
    }

    /// A slot for a page of LOD `lod`: a free one, a new one (the pool grown, within its
    /// cap), or one a resident page of a finer LOD gives up (its table entry added to
    /// `changed`); `None` when the pool is full of pages no finer than `lod`.
    fn allocate_slot(
        &mut self,
        gpu: &GpuContext,
        layout: &wgpu::BindGroupLayout,
        lod: usize,
        changed: &mut Vec<usize>,
        report: &mut SyncReport,
    ) -> Result<Option<u32>, GpuError> {
        if let Some(slot) = self.free_slots.pop() {
            return Ok(Some(slot));
        }
        if self.slots_used < self.page_cap {
            if self.slots_used == self.pool_columns * self.pool_rows {
                self.grow_pool(gpu, layout)?;
            }
            self.slots_used += 1;
            return Ok(Some(self.slots_used - 1));
        }
        let Some(finest) = (lod + 1..self.resident_per_lod.len()).rev().find(|&k| self.resident_per_lod[k] > 0) else {
            return Ok(None);
        };
        for layer in 0..2 {
            let level = self.params.levels[layer * MAX_LODS + finest];
            let range = level.table_offset as usize..(level.table_offset + level.pages_x * level.pages_y) as usize;
            if let Some(entry) = range.into_iter().find(|&e| self.resident[e].is_some()) {
                let (_, slot) = self.resident[entry].take().expect("found resident");
                self.resident_per_lod[finest] -= 1;
                changed.push(entry);
                report.pages_given_up += 1;
                return Ok(Some(slot));
            }
        }
        Ok(None)
    }

    /// Caps the pool at `pages` (at most what the device holds, and at least the slots in
    /// use): a smaller pool, for tests of a map that outgrows it.
    pub fn set_page_cap(&mut self, pages: u32) {
        self.page_cap = pages.clamp(self.slots_used.max(1), self.page_cap.max(self.slots_used.max(1)));
    }

    /// Most pages the pool may hold.
    pub fn page_cap(&self) -> u32 {
        self.page_cap
    }

    /// Doubles the pool's rows (within its cap), copying the old pool on the GPU.
    fn grow_pool(&mut self, gpu: &GpuContext, layout: &wgpu::BindGroupLayout) -> Result<(), GpuError> {
        let rows = (self.pool_rows * 2).min(self.page_cap.div_ceil(self.pool_columns)).max(self.pool_rows + 1);
        let pool = create_pool(&gpu.device, self.pool_columns, rows)?;
        let mut encoder =
            gpu.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("grow pool") });
        encoder.copy_texture_to_texture(
            self.pool.as_image_copy(),
            pool.as_image_copy(),
            wgpu::Extent3d {
                width: self.pool_columns * PAGE_SIDE,
                height: self.pool_rows * PAGE_SIDE,
                depth_or_array_layers: 1,
            },
        );
        gpu.queue.submit([encoder.finish()]);
        self.pool = pool;
        self.pool_rows = rows;
        self.bind_group = create_bind_group(
            &gpu.device,
            layout,
            &self.params_buffer,
            &self.cell_lod_buffer,
            &self.page_table_buffer,
            &self.pool,
        );
        Ok(())
    }

    pub fn bind_group(&self) -> &wgpu::BindGroup {
        &self.bind_group
    }

    pub fn params(&self) -> &LightmapParams {
        &self.params
    }

    /// Pool capacity in pages.
    pub fn capacity(&self) -> u32 {
        self.pool_columns * self.pool_rows
    }

    /// Reads back the pixels the GPU holds for page `index` of LOD `lod` of `layer` (`None`:
    /// no page there). For tests and debugging.
    pub fn read_page(
        &self,
        gpu: &GpuContext,
        layer: Layer,
        lod: usize,
        index: usize,
    ) -> Result<Option<Vec<[f32; 4]>>, GpuError> {
        let entry = self.params.levels[layer as usize * MAX_LODS + lod].table_offset as usize + index;
        let Some((_, slot)) = self.resident[entry] else { return Ok(None) };
        let size = PAGE_BYTES;
        let buffer = gpu.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("page read-back"),
            size,
            usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
            mapped_at_creation: false,
        });
        let mut encoder =
            gpu.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("read page") });
        let (col, row) = (slot % self.pool_columns, slot / self.pool_columns);
        encoder.copy_texture_to_buffer(
            wgpu::TexelCopyTextureInfo {
                texture: &self.pool,
                mip_level: 0,
                origin: wgpu::Origin3d { x: col * PAGE_SIDE, y: row * PAGE_SIDE, z: 0 },
                aspect: wgpu::TextureAspect::All,
            },
            wgpu::TexelCopyBufferInfo {
                buffer: &buffer,
                layout: wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(PAGE_SIDE * TEXEL_BYTES),
                    rows_per_image: Some(PAGE_SIDE),
                },
            },
            wgpu::Extent3d { width: PAGE_SIDE, height: PAGE_SIDE, depth_or_array_layers: 1 },
        );
        gpu.queue.submit([encoder.finish()]);
        let bytes = gpu.read_buffer(&buffer, size)?;
        Ok(Some(cast_slice::<u8, [f32; 4]>(&bytes).to_vec()))
    }
}

fn create_pool(device: &wgpu::Device, columns: u32, rows: u32) -> Result<wgpu::Texture, GpuError> {
    let max = device.limits().max_texture_dimension_2d;
    if rows * PAGE_SIDE > max {
        return Err(GpuError::Lightmap(format!(
            "the shown light map needs more than {} pages, the most a {max}² texture holds",
            columns * (max / PAGE_SIDE)
        )));
    }
    Ok(device.create_texture(&wgpu::TextureDescriptor {
        label: Some("lightmap page pool"),
        size: wgpu::Extent3d { width: columns * PAGE_SIDE, height: rows * PAGE_SIDE, depth_or_array_layers: 1 },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format: POOL_FORMAT,
        usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST | wgpu::TextureUsages::COPY_SRC,
        view_formats: &[],
    }))
}

/// Group 1 over the mirror's buffers and pool (or a placeholder's).
pub fn create_bind_group(
    device: &wgpu::Device,
    layout: &wgpu::BindGroupLayout,
    params: &wgpu::Buffer,
    cell_lod: &wgpu::Buffer,
    page_table: &wgpu::Buffer,
    pool: &wgpu::Texture,
) -> wgpu::BindGroup {
    let view = pool.create_view(&wgpu::TextureViewDescriptor::default());
    device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("lightmap"),
        layout,
        entries: &[
            wgpu::BindGroupEntry { binding: 0, resource: params.as_entire_binding() },
            wgpu::BindGroupEntry { binding: 1, resource: cell_lod.as_entire_binding() },
            wgpu::BindGroupEntry { binding: 2, resource: page_table.as_entire_binding() },
            wgpu::BindGroupEntry { binding: 3, resource: wgpu::BindingResource::TextureView(&view) },
        ],
    })
}

/// Writes `value(i)` for each index in `changed` (ascending) into a u32 buffer, one write per
/// contiguous run; returns the bytes written.
fn write_runs(gpu: &GpuContext, buffer: &wgpu::Buffer, changed: &[usize], value: impl Fn(usize) -> u32) -> u64 {
    let mut bytes = 0u64;
    let mut i = 0;
    while i < changed.len() {
        let start = changed[i];
        let mut end = start + 1;
        while i + 1 < changed.len() && changed[i + 1] == end {
            i += 1;
            end += 1;
        }
        let run: Vec<u32> = (start..end).map(&value).collect();
        gpu.queue.write_buffer(buffer, 4 * start as u64, cast_slice(&run));
        bytes += 4 * run.len() as u64;
        i += 1;
    }
    bytes
}
