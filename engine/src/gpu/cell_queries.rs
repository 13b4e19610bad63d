//! Occlusion queries over cells (`cell_query.wgsl`), for the query-grid culler
//! ([`super::QueryGridCuller`], after seed 001): the objects the culler keeps are drawn to depth, then
//! each queried cell's box inside an occlusion query of its own against that depth. The results are mapped
//! when the GPU gets to them and read at a later frame, which never waits for its own queries.

use super::indirect::{indirect_buffer, object_draws, position_vertex_state};
use super::interface::GpuView;
use super::scene::GpuScene;
use super::view_cull::view_buffer;
use super::{GpuContext, GpuError};
use crate::camera::{Camera, DepthConvention};

const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;
/// Bytes of one resolved occlusion query: the samples that passed, as a `u64`.
const QUERY_BYTES: u64 = wgpu::QUERY_SIZE as u64;

/// One queried cell's box, camera-relative: its near and far corners (`boxes` in `cell_query.wgsl`; `w`
/// unused).
pub type CellBox = [[f32; 4]; 2];

/// The depth target, the two pipelines and the query sets of the cell queries, with the scene they draw.
pub struct CellQueries {
    scene: GpuScene,
    depth: wgpu::Texture,
    /// Objects to depth, for reversed depth then for the others (`draw.wgsl`'s vertex stage only).
    depth_pipelines: [wgpu::RenderPipeline; 2],
    /// Cell boxes tested against depth, likewise.
    box_pipelines: [wgpu::RenderPipeline; 2],
    view: wgpu::Buffer,
    /// Query sets of [`wgpu::QUERY_SET_MAX_QUERIES`] queries each, one render pass each; grown on demand.
    query_sets: Vec<wgpu::QuerySet>,
    in_flight: Option<InFlight>,
}

/// A frame's queries on their way back.
struct InFlight {
    staging: wgpu::Buffer,
    submission: wgpu::SubmissionIndex,
    mapped: std::sync::mpsc::Receiver<Result<(), wgpu::BufferAsyncError>>,
    queries: usize,
}

impl CellQueries {
    /// The queries drawing `scene`'s objects into a `width` x `height` depth target.
    pub fn new(context: &GpuContext, scene: GpuScene, (width, height): (u32, u32)) -> Self {
        let draw = context.shader("query grid depth", cullet_shaders::DRAW);
        let boxes = context.shader("cell query", cullet_shaders::CELL_QUERY);
        let pipeline = |label, vertex: wgpu::VertexState<'_>, cull_mode, write, compare| {
            context.device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                label: Some(label),
                layout: None,
                vertex,
                primitive: wgpu::PrimitiveState { cull_mode, ..Default::default() },
                depth_stencil: Some(wgpu::DepthStencilState {
                    format: DEPTH_FORMAT,
                    depth_write_enabled: Some(write),
                    depth_compare: Some(compare),
                    stencil: Default::default(),
                    bias: Default::default(),
                }),
                multisample: Default::default(),
                fragment: None,
                multiview_mask: None,
                cache: None,
            })
        };
        let box_vertex = || wgpu::VertexState {
            module: &boxes,
            entry_point: Some("vs"),
            compilation_options: Default::default(),
            buffers: &[],
        };
        use wgpu::CompareFunction::{Greater, GreaterEqual, Less, LessEqual};
        let back = Some(wgpu::Face::Back);
        Self {
            scene,
            depth: depth_target(context, width, height),
            depth_pipelines: [
                pipeline("query grid depth", position_vertex_state(&draw), back, true, Greater),
                pipeline("query grid depth", position_vertex_state(&draw), back, true, Less),
            ],
            box_pipelines: [
                pipeline("cell query", box_vertex(), None, false, GreaterEqual),
                pipeline("cell query", box_vertex(), None, false, LessEqual),
            ],
            view: view_buffer(context, "query grid view"),
            query_sets: Vec::new(),
            in_flight: None,
        }
    }

    /// The scene the depth is drawn from; bring its instances up to date as objects move
    /// ([`GpuScene::write_instances`]).
    pub fn scene_mut(&mut self) -> &mut GpuScene {
        &mut self.scene
    }

    /// The depth target's width and height.
    pub fn size(&self) -> (u32, u32) {
        (self.depth.width(), self.depth.height())
    }

    /// Draws into a `width` x `height` depth target from now on.
    pub fn resize(&mut self, context: &GpuContext, width: u32, height: u32) {
        self.depth = depth_target(context, width, height);
    }

    /// Whether a frame's queries are on their way back (submitted, not yet taken).
    pub fn in_flight(&self) -> bool {
        self.in_flight.is_some()
    }

    /// Records and submits one frame through `camera`: the instances at `drawn` (store slots, ascending) to
    /// depth, each whole mesh in one draw, then one occlusion query per box of `boxes`, in order. The results
    /// come back through [`CellQueries::take_results`].
    ///
    /// # Errors
    /// [`GpuError::SlotOutOfRange`] for a slot of `drawn` that is not an instance of the scene (nothing is
    /// submitted).
    ///
    /// # Panics
    /// Where the last frame's queries are still in flight: take them first.
    pub fn submit(
        &mut self,
        context: &GpuContext,
        camera: &Camera,
        drawn: &[u32],
        boxes: &[CellBox],
    ) -> Result<(), GpuError> {
        assert!(self.in_flight.is_none(), "the last frame's cell queries are still in flight");
        let instances = self.scene.instances().len();
        if let Some(&slot) = drawn.iter().find(|&&slot| slot as usize >= instances) {
            return Err(GpuError::SlotOutOfRange { slot, instances });
        }
        let max = wgpu::QUERY_SET_MAX_QUERIES as usize;
        while self.query_sets.len() * max < boxes.len() {
            self.query_sets.push(context.device.create_query_set(&wgpu::QuerySetDescriptor {
                label: Some("cell queries"),
                ty: wgpu::QueryType::Occlusion,
                count: wgpu::QUERY_SET_MAX_QUERIES,
            }));
        }
        let view = GpuView::of_camera(camera, self.size());
        context.queue.write_buffer(&self.view, 0, bytemuck::bytes_of(&view));
        let reversed = usize::from(camera.depth != DepthConvention::Reversed);
        let draws = object_draws(&self.scene.library, self.scene.instances(), drawn.iter().copied());
        let box_buffer = {
            use wgpu::util::DeviceExt;
            let contents: &[u8] = if boxes.is_empty() { &[0; 32] } else { bytemuck::cast_slice(boxes) };
            context.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("cell boxes"),
                contents,
                usage: wgpu::BufferUsages::STORAGE,
            })
        };
        let depth_pipeline = &self.depth_pipelines[reversed];
        let box_pipeline = &self.box_pipelines[reversed];
        let depth_bindings = context.bind_buffers(
            "query grid depth",
            &depth_pipeline.get_bind_group_layout(0),
            &[(0, &self.view), (1, &self.scene.instances)],
        );
        let box_bindings = context.bind_buffers(
            "cell query",
            &box_pipeline.get_bind_group_layout(0),
            &[(0, &self.view), (1, &box_buffer)],
        );
        let resolve_bytes = (boxes.len() as u64 * QUERY_BYTES).max(QUERY_BYTES);
        let buffer = |label, usage| {
            context.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: resolve_bytes,
                usage,
                mapped_at_creation: false,
            })
        };
        let resolved = buffer("cell query results", wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC);
        let staging = buffer("cell query read", wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST);

        let mut encoder = context.device.create_command_encoder(&Default::default());
        let depth_view = self.depth.create_view(&Default::default());
        let clear_depth = if reversed == 0 { 0.0 } else { 1.0 };
        // One render pass per query set: the first clears the depth and draws the objects.
        let chunks = boxes.len().div_ceil(max).max(1);
        for chunk in 0..chunks {
            let first = chunk * max;
            let count = boxes.len().saturating_sub(first).min(max) as u32;
            let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("cell queries"),
                color_attachments: &[],
                depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                    view: &depth_view,
                    depth_ops: Some(wgpu::Operations {
                        load: if chunk == 0 { wgpu::LoadOp::Clear(clear_depth) } else { wgpu::LoadOp::Load },
                        store: wgpu::StoreOp::Store,
                    }),
                    stencil_ops: None,
                }),
                occlusion_query_set: (count > 0).then(|| &self.query_sets[chunk]),
                ..Default::default()
            });
            if chunk == 0 && !draws.is_empty() {
                let args = indirect_buffer(context, "query grid depth draws", &draws);
                pass.set_pipeline(depth_pipeline);
                pass.set_bind_group(0, &depth_bindings, &[]);
                pass.set_vertex_buffer(0, self.scene.positions.slice(..));
                pass.set_index_buffer(self.scene.cluster_indices.slice(..), wgpu::IndexFormat::Uint32);
                pass.multi_draw_indexed_indirect(&args, 0, draws.len() as u32);
            }
            pass.set_pipeline(box_pipeline);
            pass.set_bind_group(0, &box_bindings, &[]);
            for query in 0..count {
                let cell = first as u32 + query;
                pass.begin_occlusion_query(query);
                pass.draw(0..36, cell..cell + 1);
                pass.end_occlusion_query();
            }
            drop(pass);
            if count > 0 {
                encoder.resolve_query_set(&self.query_sets[chunk], 0..count, &resolved, first as u64 * QUERY_BYTES);
            }
        }
        encoder.copy_buffer_to_buffer(&resolved, 0, &staging, 0, resolve_bytes);
        let submission = context.queue.submit([encoder.finish()]);
        let (sender, mapped) = std::sync::mpsc::channel();
        staging.slice(..).map_async(wgpu::MapMode::Read, move |result| {
            let _ = sender.send(result);
        });
        self.in_flight = Some(InFlight { staging, submission, mapped, queries: boxes.len() });
        Ok(())
    }

    /// The samples that passed each box of the last [`CellQueries::submit`], in order, once the GPU has
    /// finished them: `None` where nothing is in flight, or where the GPU is not done and `wait` is false (the
    /// results stay in flight for a later call).
    ///
    /// # Errors
    /// [`GpuError::Lost`] when the device is lost or the map fails (the results are dropped).
    pub fn take_results(&mut self, context: &GpuContext, wait: bool) -> Result<Option<Vec<u64>>, GpuError> {
        let Some(in_flight) = &self.in_flight else { return Ok(None) };
        let lost = |what: &str, error: &dyn std::fmt::Display| GpuError::Lost(format!("{what}: {error}"));
        let poll = if wait {
            wgpu::PollType::Wait { submission_index: Some(in_flight.submission.clone()), timeout: None }
        } else {
            wgpu::PollType::Poll
        };
        let polled = context.device.poll(poll);
        let received = if wait {
            in_flight.mapped.recv().map_err(|_| std::sync::mpsc::TryRecvError::Disconnected)
        } else {
            in_flight.mapped.try_recv()
        };
        let mapped = match received {
            Ok(mapped) => mapped,
            Err(std::sync::mpsc::TryRecvError::Empty) if polled.is_ok() => return Ok(None),
            Err(error) => {
                self.in_flight = None;
                return Err(polled.err().map_or_else(|| lost("map callback dropped", &error), |e| lost("poll", &e)));
            }
        };
        let in_flight = self.in_flight.take().expect("checked above");
        mapped.map_err(|e| lost("map failed", &e))?;
        let bytes = in_flight.staging.slice(..).get_mapped_range().map_err(|e| lost("mapped range", &e))?.to_vec();
        let samples: &[u64] = bytemuck::cast_slice(&bytes);
        Ok(Some(samples[..in_flight.queries].to_vec()))
    }
}

fn depth_target(context: &GpuContext, width: u32, height: u32) -> wgpu::Texture {
    context.device.create_texture(&wgpu::TextureDescriptor {
        label: Some("query grid depth"),
        size: wgpu::Extent3d { width: width.max(1), height: height.max(1), depth_or_array_layers: 1 },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format: DEPTH_FORMAT,
        usage: wgpu::TextureUsages::RENDER_ATTACHMENT,
        view_formats: &[],
    })
}
