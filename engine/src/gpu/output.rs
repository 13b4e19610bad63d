//! What a GPU frame produces, read back: the [`GpuCounters`] of every test, the [`GpuPassTimes`] from
//! timestamp queries where the adapter has them, and both with the gating flags in a [`GpuFrameOutput`].

use super::cluster_cull::ClusterVerdict;
use super::interface::counter;
use super::triangle_cull::TriangleVerdict;
use super::{GpuContext, GpuError};
use std::time::Duration;

/// Counters of one frame, read back from the GPU.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct GpuCounters {
    /// Instances submitted (the CPU stages' survivors).
    pub instances: u32,
    /// Clusters tested.
    pub clusters_in: u32,
    /// Clusters culled by the frustum, cone, HZB and small tests.
    pub clusters_frustum: u32,
    /// See `clusters_frustum`.
    pub clusters_cone: u32,
    /// See `clusters_frustum`.
    pub clusters_hzb: u32,
    /// See `clusters_frustum`.
    pub clusters_small: u32,
    /// Clusters kept.
    pub clusters_out: u32,
    /// Triangles tested.
    pub triangles_in: u32,
    /// Triangles culled as degenerate, back-facing, off-screen and small.
    pub triangles_degenerate: u32,
    /// See `triangles_degenerate`.
    pub triangles_backface: u32,
    /// See `triangles_degenerate`.
    pub triangles_frustum: u32,
    /// See `triangles_degenerate`.
    pub triangles_small: u32,
    /// Triangles kept.
    pub triangles_out: u32,
    /// Indirect draws issued (clusters with surviving triangles), all in one multi-draw.
    pub draws: u32,
    /// Clusters the late phase of two-phase occlusion kept that its early phase had already drawn (0 in a
    /// frame of one phase).
    pub clusters_drawn_early: u32,
}

/// Bytes of the counter buffer.
pub(crate) const COUNTER_BYTES: u64 = counter::COUNTER_COUNT as u64 * 4;

impl GpuCounters {
    /// The counters of `instances` instances from the counter buffer's slots `c` (see [`counter`]).
    pub(crate) fn from_slots(instances: u32, c: &[u32]) -> Self {
        use counter::*;
        let slot = |index: u32| c[index as usize];
        Self {
            instances,
            clusters_in: slot(CLUSTERS_IN),
            clusters_frustum: slot(CLUSTERS_FRUSTUM),
            clusters_cone: slot(CLUSTERS_CONE),
            clusters_hzb: slot(CLUSTERS_HZB),
            clusters_small: slot(CLUSTERS_SMALL),
            clusters_out: slot(CLUSTERS_OUT),
            triangles_in: slot(TRIANGLES_IN),
            triangles_degenerate: slot(TRIANGLES_DEGENERATE),
            triangles_backface: slot(TRIANGLES_BACKFACE),
            triangles_frustum: slot(TRIANGLES_FRUSTUM),
            triangles_small: slot(TRIANGLES_SMALL),
            triangles_out: slot(TRIANGLES_OUT),
            draws: slot(DRAWS),
            clusters_drawn_early: slot(CLUSTERS_DRAWN_EARLY),
        }
    }

    /// Every counter, in the order of the fields.
    fn to_array(self) -> [u32; 15] {
        [
            self.instances,
            self.clusters_in,
            self.clusters_frustum,
            self.clusters_cone,
            self.clusters_hzb,
            self.clusters_small,
            self.clusters_out,
            self.triangles_in,
            self.triangles_degenerate,
            self.triangles_backface,
            self.triangles_frustum,
            self.triangles_small,
            self.triangles_out,
            self.draws,
            self.clusters_drawn_early,
        ]
    }

    /// The inverse of [`GpuCounters::to_array`].
    fn from_array(c: [u32; 15]) -> Self {
        let [instances, counters @ .., drawn_early] = c;
        let mut slots = [0; counter::COUNTER_COUNT as usize];
        slots[..counters.len()].copy_from_slice(&counters);
        slots[counter::CLUSTERS_DRAWN_EARLY as usize] = drawn_early;
        Self::from_slots(instances, &slots)
    }

    /// Both counters added up, field by field.
    pub fn plus(&self, other: &GpuCounters) -> GpuCounters {
        let (a, b) = (self.to_array(), other.to_array());
        GpuCounters::from_array(std::array::from_fn(|i| a[i] + b[i]))
    }

    /// These counters less `part`, which they include (a view's share of counters added up with
    /// [`GpuCounters::plus`]).
    pub(crate) fn less(&self, part: &GpuCounters) -> GpuCounters {
        let (a, b) = (self.to_array(), part.to_array());
        GpuCounters::from_array(std::array::from_fn(|i| a[i] - b[i]))
    }

    /// How many clusters `verdict` accounts for.
    pub fn clusters(&self, verdict: ClusterVerdict) -> u32 {
        match verdict {
            ClusterVerdict::Keep => self.clusters_out,
            ClusterVerdict::Frustum => self.clusters_frustum,
            ClusterVerdict::Cone => self.clusters_cone,
            ClusterVerdict::Hzb => self.clusters_hzb,
            ClusterVerdict::Small => self.clusters_small,
        }
    }

    /// How many triangles `verdict` accounts for.
    pub fn triangles(&self, verdict: TriangleVerdict) -> u32 {
        match verdict {
            TriangleVerdict::Keep => self.triangles_out,
            TriangleVerdict::Degenerate => self.triangles_degenerate,
            TriangleVerdict::Backface => self.triangles_backface,
            TriangleVerdict::Frustum => self.triangles_frustum,
            TriangleVerdict::Small => self.triangles_small,
        }
    }
}

/// GPU time of each pass of a frame, from timestamp queries.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct GpuPassTimes {
    /// HZB upload reduction.
    pub hzb: Duration,
    /// Cluster culling.
    pub clusters: Duration,
    /// Triangle-pass dispatch and triangle culling.
    pub triangles: Duration,
    /// The draw.
    pub draw: Duration,
    /// Two-phase occlusion's late phase (zero in a frame of one phase): the early phase's depth reduced and
    /// merged with the CPU's HZB.
    pub merge: Duration,
    /// See `merge`: the late cluster pass.
    pub late_clusters: Duration,
    /// See `merge`: the late triangle pass.
    pub late_triangles: Duration,
    /// See `merge`: the late draw.
    pub late_draw: Duration,
    /// See `merge`: the frame's final depth merged again (its reduction untimed, as the first merge's).
    pub final_merge: Duration,
    /// See `merge`: the pass taking the marks of the clusters the final depth hides.
    pub final_marks: Duration,
    /// The late phase's occluder step, where it ran ([`super::interface::VIEW_PHASE_LATE_OCCLUDERS`]; zero
    /// otherwise): its cluster pass.
    pub occluder_clusters: Duration,
    /// See `occluder_clusters`: its triangle pass.
    pub occluder_triangles: Duration,
    /// See `occluder_clusters`: its draw.
    pub occluder_draw: Duration,
    /// See `occluder_clusters`: the depth merged again after its draw (its reduction untimed).
    pub occluder_merge: Duration,
}

impl GpuPassTimes {
    /// The mean over `frames`, or `None` unless every frame was timed.
    pub fn mean(frames: &[GpuFrameOutput]) -> Option<Self> {
        let times: Option<Vec<&Self>> = frames.iter().map(|f| f.pass_times.as_ref()).collect();
        let times = times.filter(|t| !t.is_empty())?;
        let n = times.len() as u32;
        let sum = |f: fn(&Self) -> Duration| times.iter().map(|t| f(t)).sum::<Duration>() / n;
        Some(Self {
            hzb: sum(|t| t.hzb),
            clusters: sum(|t| t.clusters),
            triangles: sum(|t| t.triangles),
            draw: sum(|t| t.draw),
            merge: sum(|t| t.merge),
            late_clusters: sum(|t| t.late_clusters),
            late_triangles: sum(|t| t.late_triangles),
            late_draw: sum(|t| t.late_draw),
            final_merge: sum(|t| t.final_merge),
            final_marks: sum(|t| t.final_marks),
            occluder_clusters: sum(|t| t.occluder_clusters),
            occluder_triangles: sum(|t| t.occluder_triangles),
            occluder_draw: sum(|t| t.occluder_draw),
            occluder_merge: sum(|t| t.occluder_merge),
        })
    }
}

impl std::fmt::Display for GpuPassTimes {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let us = |d: Duration| d.as_secs_f64() * 1e6;
        write!(
            f,
            "HZB {:.1} us, clusters {:.1} us, triangles {:.1} us, draw {:.1} us",
            us(self.hzb),
            us(self.clusters),
            us(self.triangles),
            us(self.draw)
        )?;
        if self.merge > Duration::ZERO {
            write!(
                f,
                "; late phase: merge {:.1} us, clusters {:.1} us, triangles {:.1} us, draw {:.1} us, final merge \
                 {:.1} us, final marks {:.1} us",
                us(self.merge),
                us(self.late_clusters),
                us(self.late_triangles),
                us(self.late_draw),
                us(self.final_merge),
                us(self.final_marks)
            )?;
        }
        if self.occluder_merge > Duration::ZERO {
            write!(
                f,
                "; occluder step: clusters {:.1} us, triangles {:.1} us, draw {:.1} us, merge {:.1} us",
                us(self.occluder_clusters),
                us(self.occluder_triangles),
                us(self.occluder_draw),
                us(self.occluder_merge)
            )?;
        }
        Ok(())
    }
}

/// Timestamp queries around each pass, where the adapter has them.
pub(crate) struct PassTimer {
    pub(crate) queries: wgpu::QuerySet,
    pub(crate) resolve: wgpu::Buffer,
    /// Nanoseconds per tick.
    period: f64,
}

/// Passes timed, two timestamps each: the HZB build, clusters, triangles, draw, then two-phase occlusion's
/// merge, late clusters, triangles and draw, final merge and marks, and the late phase's occluder step's
/// clusters, triangles, draw and merge.
pub(crate) const TIMED_PASSES: u32 = 14;
/// The passes of a frame of two phases without the occluder step: the first ten.
pub(crate) const TWO_PHASE_PASSES: u32 = 10;
/// The passes of a frame of one phase: the first four.
pub(crate) const ONE_PHASE_PASSES: u32 = 4;

impl PassTimer {
    pub(crate) fn new(context: &GpuContext) -> Option<Self> {
        if !context.has_timestamps {
            return None;
        }
        Some(Self {
            queries: context.device.create_query_set(&wgpu::QuerySetDescriptor {
                label: Some("pass timestamps"),
                ty: wgpu::QueryType::Timestamp,
                count: 2 * TIMED_PASSES,
            }),
            resolve: context.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("timestamp resolve"),
                size: 8 * u64::from(2 * TIMED_PASSES),
                usage: wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
                mapped_at_creation: false,
            }),
            period: f64::from(context.queue.get_timestamp_period()),
        })
    }

    pub(crate) fn compute(&self, pass: u32) -> wgpu::ComputePassTimestampWrites<'_> {
        wgpu::ComputePassTimestampWrites {
            query_set: &self.queries,
            beginning_of_pass_write_index: Some(2 * pass),
            end_of_pass_write_index: Some(2 * pass + 1),
        }
    }

    pub(crate) fn render(&self, pass: u32) -> wgpu::RenderPassTimestampWrites<'_> {
        wgpu::RenderPassTimestampWrites {
            query_set: &self.queries,
            beginning_of_pass_write_index: Some(2 * pass),
            end_of_pass_write_index: Some(2 * pass + 1),
        }
    }

    /// Resolves the timestamps of the first `passes` passes into the resolve buffer.
    pub(crate) fn resolve(&self, encoder: &mut wgpu::CommandEncoder, passes: u32) {
        encoder.resolve_query_set(&self.queries, 0..2 * passes, &self.resolve, 0);
    }

    /// The times of the first `passes` passes (the others zero), once resolved.
    pub(crate) fn read(&self, context: &GpuContext, passes: u32) -> Result<GpuPassTimes, GpuError> {
        let bytes = context.read_buffer(&self.resolve, 16 * u64::from(passes))?;
        let ticks: &[u64] = bytemuck::cast_slice(&bytes);
        let span = |pass: usize| match ticks.get(2 * pass..2 * pass + 2) {
            Some(&[start, end]) => Duration::from_nanos((end.saturating_sub(start) as f64 * self.period) as u64),
            _ => Duration::ZERO,
        };
        Ok(GpuPassTimes {
            hzb: span(0),
            clusters: span(1),
            triangles: span(2),
            draw: span(3),
            merge: span(4),
            late_clusters: span(5),
            late_triangles: span(6),
            late_draw: span(7),
            final_merge: span(8),
            final_marks: span(9),
            occluder_clusters: span(10),
            occluder_triangles: span(11),
            occluder_draw: span(12),
            occluder_merge: span(13),
        })
    }
}

/// What one frame produced, read back.
#[derive(Clone, Debug, Default)]
pub struct GpuFrameOutput {
    /// The counters.
    pub counters: GpuCounters,
    /// GPU time per pass, where the adapter has timestamp queries.
    pub pass_times: Option<GpuPassTimes>,
    /// Wall time from submitting the frame until its counters were back on the CPU.
    pub wall_time: Duration,
    /// The cluster pass was skipped, for too few clusters to pay ([`super::GpuGating::tiny_scene_clusters`]) or
    /// for removing too little lately ([`super::GpuGating::min_cluster_benefit`]): every candidate cluster went
    /// on to the next pass.
    pub cluster_pass_skipped: bool,
    /// The triangle pass was skipped for removing too little lately
    /// ([`super::GpuGating::min_triangle_benefit`]): the surviving clusters were drawn whole.
    pub triangle_pass_skipped: bool,
    /// The counters of each sun cascade's culling, nearest first, where the frame drew shadow maps
    /// ([`super::GpuCuller::run_world`] with [`crate::pipeline::LightViews`]); empty otherwise.
    pub light_views: Vec<GpuCounters>,
    /// `counters` are the previous frame's ([`super::ReadBack::Late`]; zero on the first such frame), and
    /// `wall_time` ran from submitting this frame until they were back.
    pub counters_late: bool,
    /// Each phase's counters, where the frame ran in two ([`super::GpuCullSettings::two_phase`]); `counters`
    /// then adds both up (a cluster drawn early is tested, and counted, in both).
    pub phases: Option<PhaseCounters>,
}

/// The counters of a frame's two phases of occlusion culling ([`super::GpuCullSettings::two_phase`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PhaseCounters {
    /// The early phase: the clusters visible last frame, tested against the CPU's HZB and drawn.
    pub early: GpuCounters,
    /// The late phase: every cluster tested against the merged HZB; `clusters_out` and what follows count
    /// only those drawn late, `clusters_drawn_early` those it kept that the early phase had drawn. Where the
    /// occluder step ran, its counters are included.
    pub late: GpuCounters,
    /// The late phase's occluder step ([`super::interface::VIEW_PHASE_LATE_OCCLUDERS`]), where it ran: the
    /// clusters it drew first (each counted in, and out) and their triangles.
    pub late_occluders: Option<GpuCounters>,
}

impl GpuFrameOutput {
    /// Both outputs added up: counters, pass times and wall time (the batches of one frame).
    pub fn plus(&self, other: &GpuFrameOutput) -> GpuFrameOutput {
        let counters = self.counters.plus(&other.counters);
        let pass_times = self.pass_times.zip(other.pass_times).map(|(a, b)| GpuPassTimes {
            hzb: a.hzb + b.hzb,
            clusters: a.clusters + b.clusters,
            triangles: a.triangles + b.triangles,
            draw: a.draw + b.draw,
            merge: a.merge + b.merge,
            late_clusters: a.late_clusters + b.late_clusters,
            late_triangles: a.late_triangles + b.late_triangles,
            late_draw: a.late_draw + b.late_draw,
            final_merge: a.final_merge + b.final_merge,
            final_marks: a.final_marks + b.final_marks,
            occluder_clusters: a.occluder_clusters + b.occluder_clusters,
            occluder_triangles: a.occluder_triangles + b.occluder_triangles,
            occluder_draw: a.occluder_draw + b.occluder_draw,
            occluder_merge: a.occluder_merge + b.occluder_merge,
        });
        GpuFrameOutput {
            counters,
            pass_times,
            wall_time: self.wall_time + other.wall_time,
            cluster_pass_skipped: self.cluster_pass_skipped || other.cluster_pass_skipped,
            triangle_pass_skipped: self.triangle_pass_skipped || other.triangle_pass_skipped,
            // Only a frame's first batch draws the shadow maps.
            light_views: if self.light_views.is_empty() { &other.light_views } else { &self.light_views }.clone(),
            counters_late: self.counters_late || other.counters_late,
            phases: self.phases.or(other.phases),
        }
    }
}
