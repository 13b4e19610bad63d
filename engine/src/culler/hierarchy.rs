//! A bounding volume hierarchy over the objects (seed 000 §19.4), culled as a tree: the alternative to the
//! linear arrays the design chose (after Frostbite), behind the same [`Culler`] interface so that the two are
//! measured side by side.
//!
//! Built top-down, each node's objects split at the median of their centres along the longest axis of the
//! centres' box, down to leaves of at most [`HierarchySettings::leaf_size`] objects, subtrees of many objects
//! in parallel. Nodes are laid out depth first, so that a subtree's nodes and objects are each one contiguous
//! range. Where objects moved, their leaves and ancestors are refitted bottom-up; where objects came or went,
//! the tree is built again. Either is counted in the frame's frustum time.
//!
//! The frustum: each node's box against the planes its parent's box was not already inside (plane masking),
//! the plane that rejected the node last frame first (plane coherence); a node inside every plane keeps its
//! subtree untested. Occlusion: the occluders the occlusion stage would choose at the same budget, rasterized
//! into the same depth pyramid; a node whose box the pyramid hides hides its subtree untested, children
//! visited nearest first.

use super::adaptive::BenefitGate;
use super::{
    AdaptiveSettings, CullScene, Culled, Culler, OcclusionSettings, StoreChange, ViewStats, frustum_or_keep_everything,
};
use crate::bounds::BoundsStore;
use crate::camera::Camera;
use crate::depth::{DepthPyramid, ScreenView};
use crate::frustum::Frustum;
use crate::occlusion::box_occluded;
use crate::parallel::{self, Region, Stage};
use crate::raster::rasterize;
use crate::visible::{SharedVisibleSet, VisibleSet};
use glam::Vec3;
use std::sync::atomic::{AtomicU8, Ordering};
use std::time::Instant;

/// [`Node::right`] of a leaf.
const LEAF: u32 = u32::MAX;
/// Subtrees of more objects than this are built and culled as rayon tasks of their own.
const PARALLEL_ABOVE: u32 = 8192;
/// Store slots a task handles where the tree's work is per slot (boxes, changes).
const SLOTS_PER_TASK: usize = 16384;
/// [`Bvh::coherence`] of a node no plane rejected last frame.
const NO_PLANE: u8 = u8::MAX;

/// How the hierarchy culls.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HierarchySettings {
    /// Most objects in a leaf.
    pub leaf_size: u32,
    /// The occlusion stage's settings: its buffer, raster mode and occluder budget (`enabled: false` for the
    /// frustum alone).
    pub occlusion: OcclusionSettings,
    /// When occlusion is skipped for removing too little lately: the occlusion stage's benefit gate
    /// ([`AdaptiveSettings::min_occlusion_benefit`], its frames and re-probes); [`AdaptiveSettings::fixed`]
    /// never skips.
    pub adaptive: AdaptiveSettings,
}

impl Default for HierarchySettings {
    fn default() -> Self {
        Self { leaf_size: 8, occlusion: OcclusionSettings::default(), adaptive: AdaptiveSettings::default() }
    }
}

/// A node: its box (containing every object box below it), its objects `order[first..first + count]`, and its
/// children, the next node and `right`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct Node {
    min: Vec3,
    max: Vec3,
    first: u32,
    count: u32,
    right: u32,
}

/// The tree over a store's objects.
#[derive(Debug, Default)]
pub struct Bvh {
    nodes: Vec<Node>,
    /// Store slots, each subtree's a contiguous range.
    order: Vec<u32>,
    parent: Vec<u32>,
    /// The leaf of each store slot.
    leaf_of: Vec<u32>,
    /// Each slot's box as last built or refitted: (least, greatest corner), rounded outwards.
    boxes: Vec<(Vec3, Vec3)>,
    /// Per node, the frustum plane that rejected it last frame.
    coherence: Vec<AtomicU8>,
}

/// The box of store slot `slot`, rounded outwards so that it holds the store's centre-and-extent box.
fn slot_box(store: &BoundsStore, slot: usize) -> (Vec3, Vec3) {
    let bounds = store.get(slot).expect("a slot below the store's length");
    let pad = (bounds.center.abs() + bounds.half_extent) * (4.0 * f32::EPSILON);
    (bounds.center - bounds.half_extent - pad, bounds.center + bounds.half_extent + pad)
}

/// The number of nodes of a tree over `count` objects with leaves of at most `leaf`, and over `count + 1`:
/// each node splits its objects in halves, `count / 2` to the left.
fn node_counts(count: u32, leaf: u32) -> (u32, u32) {
    if count < leaf {
        return (1, 1);
    }
    let half = count / 2;
    let (n_half, n_half_1) = node_counts(half, leaf);
    let node = |c: u32, left: u32, right: u32| if c <= leaf { 1 } else { 1 + left + right };
    if count.is_multiple_of(2) {
        (node(count, n_half, n_half), node(count + 1, n_half, n_half_1))
    } else {
        (node(count, n_half, n_half_1), node(count + 1, n_half_1, n_half_1))
    }
}

impl Bvh {
    /// The tree over every object of `store`, leaves of at most `leaf` objects (at least 1).
    pub fn build(store: &BoundsStore, leaf: u32) -> Self {
        let leaf = leaf.max(1);
        let boxes: Vec<(Vec3, Vec3)> = parallel::map_range(store.len(), SLOTS_PER_TASK, |slot| slot_box(store, slot));
        let mut order: Vec<u32> = (0..store.len() as u32).collect();
        let count = if order.is_empty() { 0 } else { node_counts(order.len() as u32, leaf).0 as usize };
        let mut nodes = vec![Node::default(); count];
        if !order.is_empty() {
            parallel::region(|region| build_subtree(&mut nodes, 0, &mut order, 0, &boxes, leaf, region));
        }
        let mut parent = vec![LEAF; nodes.len()];
        let mut leaf_of = vec![0; order.len()];
        for (index, node) in nodes.iter().enumerate() {
            if node.right == LEAF {
                for &slot in &order[node.first as usize..][..node.count as usize] {
                    leaf_of[slot as usize] = index as u32;
                }
            } else {
                parent[index + 1] = index as u32;
                parent[node.right as usize] = index as u32;
            }
        }
        let coherence = (0..nodes.len()).map(|_| AtomicU8::new(NO_PLANE)).collect();
        Self { nodes, order, parent, leaf_of, boxes, coherence }
    }

    /// Number of nodes.
    pub fn node_count(&self) -> usize {
        self.nodes.len()
    }

    /// The slots whose boxes in `store` differ from the tree's, where the caller does not know what moved.
    fn changed_slots(&self, store: &BoundsStore) -> Vec<u32> {
        let changed = parallel::map_range(store.len(), SLOTS_PER_TASK, |s| slot_box(store, s) != self.boxes[s]);
        changed.iter().enumerate().filter(|&(_, &changed)| changed).map(|(slot, _)| slot as u32).collect()
    }

    /// Refits the leaves of `slots` to their boxes in `store`, and their ancestors bottom-up.
    fn refit(&mut self, store: &BoundsStore, slots: &[u32]) {
        let mut dirty: Vec<u32> = Vec::with_capacity(slots.len());
        for &slot in slots {
            self.boxes[slot as usize] = slot_box(store, slot as usize);
            dirty.push(self.leaf_of[slot as usize]);
        }
        let mut next = Vec::new();
        while !dirty.is_empty() {
            dirty.sort_unstable();
            dirty.dedup();
            next.clear();
            // Deepest first: in a depth-first layout a child's index is above its parent's.
            for &index in dirty.iter().rev() {
                let node = self.nodes[index as usize];
                let (min, max) = if node.right == LEAF {
                    union(
                        self.order[node.first as usize..][..node.count as usize]
                            .iter()
                            .map(|&s| self.boxes[s as usize]),
                    )
                } else {
                    let (left, right) = (self.nodes[index as usize + 1], self.nodes[node.right as usize]);
                    (left.min.min(right.min), left.max.max(right.max))
                };
                self.nodes[index as usize].min = min;
                self.nodes[index as usize].max = max;
                let parent = self.parent[index as usize];
                if parent != LEAF {
                    next.push(parent);
                }
            }
            std::mem::swap(&mut dirty, &mut next);
        }
    }
}

fn union(boxes: impl Iterator<Item = (Vec3, Vec3)>) -> (Vec3, Vec3) {
    boxes.fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(min, max), (a, b)| (min.min(a), max.max(b)))
}

/// Builds the subtree whose root is `nodes[0]` (node `base` of the tree) over `order` (starting at `first` of
/// the tree's order).
/// Subtrees of more than [`PARALLEL_ABOVE`] objects are split across rayon; the others are `region`'s tasks.
fn build_subtree(
    nodes: &mut [Node],
    base: u32,
    order: &mut [u32],
    first: u32,
    boxes: &[(Vec3, Vec3)],
    leaf: u32,
    region: &Region,
) {
    let count = order.len() as u32;
    let (min, max) = union(order.iter().map(|&s| boxes[s as usize]));
    if count <= leaf {
        nodes[0] = Node { min, max, first, count, right: LEAF };
        return;
    }
    let centre = |slot: u32| {
        let (a, b) = boxes[slot as usize];
        a + b
    };
    let (low, high) = order
        .iter()
        .fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(low, high), &s| (low.min(centre(s)), high.max(centre(s))));
    let axis = (high - low).max_position();
    let half = count / 2;
    order.select_nth_unstable_by(half as usize, |&a, &b| centre(a)[axis].total_cmp(&centre(b)[axis]));
    let left_nodes = node_counts(half, leaf).0;
    nodes[0] = Node { min, max, first, count, right: base + 1 + left_nodes };
    let (left_tree, right_tree) = nodes[1..].split_at_mut(left_nodes as usize);
    let (left_order, right_order) = order.split_at_mut(half as usize);
    let mut build_left = move || build_subtree(left_tree, base + 1, left_order, first, boxes, leaf, region);
    let mut build_right =
        move || build_subtree(right_tree, base + 1 + left_nodes, right_order, first + half, boxes, leaf, region);
    if count > PARALLEL_ABOVE {
        rayon::join(|| as_task(region, half, build_left), || as_task(region, count - half, build_right));
    } else {
        build_left();
        build_right();
    }
}

/// Runs `f`, the work on a subtree of `objects` objects: a task of `region` where the subtree is one rayon
/// runs serially (at most [`PARALLEL_ABOVE`] objects), which the work-and-span accounting then counts.
fn as_task<R>(region: &Region, objects: u32, f: impl FnOnce() -> R) -> R {
    if objects > PARALLEL_ABOVE { f() } else { region.task(f) }
}

/// Where a box stands against a plane `normal . (p - origin) + d >= 0`.
enum Side {
    Outside,
    Inside,
    Crossing,
}

/// One frame's traversal: the tree, the frustum and, for occlusion, the view and pyramid.
struct Traversal<'a> {
    bvh: &'a Bvh,
    frustum: &'a Frustum,
    occlusion: Option<(&'a ScreenView, &'a DepthPyramid)>,
    eye: Vec3,
    /// Objects the frustum keeps, set by the frustum pass; read by the occlusion pass.
    frustum_visible: &'a SharedVisibleSet,
    kept: &'a SharedVisibleSet,
    frustum_only: Option<&'a VisibleSet>,
}

impl Traversal<'_> {
    fn side(&self, plane: usize, min: Vec3, max: Vec3) -> Side {
        let plane = &self.frustum.planes()[plane];
        let centre = (min + max) * 0.5 - self.frustum.origin();
        let half = (max - min) * 0.5;
        let distance = plane.normal.dot(centre) + plane.d;
        let radius = plane.normal.abs().dot(half);
        // Above the f32 rounding of the dot products, so that only what is surely outside is rejected.
        let slack = (plane.normal.abs().dot(centre.abs()) + plane.d.abs() + radius) * 4e-6;
        if distance < -radius - slack {
            Side::Outside
        } else if distance > radius + slack {
            Side::Inside
        } else {
            Side::Crossing
        }
    }

    /// The planes of `mask` that the box does not lie inside, or `None` where it lies outside one; the plane
    /// that rejected it last frame (kept in `coherence`) first.
    fn classify(&self, min: Vec3, max: Vec3, mask: u8, coherence: Option<&AtomicU8>) -> Option<u8> {
        let planes = self.frustum.planes().len();
        let first = coherence.map_or(NO_PLANE, |c| c.load(Ordering::Relaxed));
        if (first as usize) < planes
            && mask & (1 << first) != 0
            && matches!(self.side(first as usize, min, max), Side::Outside)
        {
            return None;
        }
        let mut remaining = mask;
        for plane in 0..planes {
            if mask & (1 << plane) == 0 {
                continue;
            }
            match self.side(plane, min, max) {
                Side::Outside => {
                    if let Some(c) = coherence {
                        c.store(plane as u8, Ordering::Relaxed);
                    }
                    return None;
                }
                Side::Inside => remaining &= !(1 << plane),
                Side::Crossing => {}
            }
        }
        Some(remaining)
    }

    fn hidden(&self, min: Vec3, max: Vec3) -> bool {
        self.occlusion.is_some_and(|(view, pyramid)| box_occluded(view, pyramid, min, max))
    }

    /// Culls the whole tree, as one parallel region: subtrees of more than [`PARALLEL_ABOVE`] objects split
    /// across rayon, the others its tasks.
    fn run(&self, all_planes: u8) {
        if !self.bvh.nodes.is_empty() {
            parallel::region(|region| self.visit(0, all_planes, region));
        }
    }

    /// Culls the subtree of node `index` whose parent's box lay inside every plane but those of `mask`.
    fn visit(&self, index: u32, mask: u8, region: &Region) {
        let node = self.bvh.nodes[index as usize];
        let Some(mask) = self.classify(node.min, node.max, mask, Some(&self.bvh.coherence[index as usize])) else {
            return;
        };
        if self.frustum_only.is_some() && self.hidden(node.min, node.max) {
            return;
        }
        let slots = &self.bvh.order[node.first as usize..][..node.count as usize];
        if node.right == LEAF || (mask == 0 && self.frustum_only.is_none()) {
            for &slot in slots {
                self.object(slot, mask);
            }
            return;
        }
        let (left, right) = (index + 1, node.right);
        // Nearest child first: a renderer drawing in this order draws occluders before what they hide.
        let distance = |child: u32| {
            let n = self.bvh.nodes[child as usize];
            ((n.min + n.max) * 0.5 - self.eye).length_squared()
        };
        let (near, far) = if distance(left) <= distance(right) { (left, right) } else { (right, left) };
        if node.count > PARALLEL_ABOVE {
            let subtree = |child: u32| {
                let objects = self.bvh.nodes[child as usize].count;
                as_task(region, objects, || self.visit(child, mask, region));
            };
            rayon::join(|| subtree(near), || subtree(far));
        } else {
            self.visit(near, mask, region);
            self.visit(far, mask, region);
        }
    }

    /// One object in a node whose box lay inside every plane but those of `mask`.
    fn object(&self, slot: u32, mask: u8) {
        match self.frustum_only {
            None => {
                let (min, max) = self.bvh.boxes[slot as usize];
                if mask == 0 || self.classify(min, max, mask, None).is_some() {
                    self.frustum_visible.set(slot);
                }
            }
            Some(frustum_visible) => {
                if frustum_visible.contains(slot as usize) {
                    let (min, max) = self.bvh.boxes[slot as usize];
                    if !self.hidden(min, max) {
                        self.kept.set(slot);
                    }
                }
            }
        }
    }
}

/// The hierarchy behind [`Culler`]: frustum and occlusion culled down a bounding volume hierarchy instead of
/// over the linear arrays. Conservative where its occlusion settings are.
///
/// # Example
/// ```
/// use cullet::culler::{CullScene, Culler, HierarchyCuller};
/// # use bevy_ecs::prelude::*;
/// # use cullet::prelude::*;
/// # use glam::Vec3;
/// # let (mut world, mut schedule) = (World::new(), Schedule::default());
/// # cullet::install(&mut world, &mut schedule, PipelineSettings::default());
/// # world.insert_resource(Camera::looking_at(Vec3::ZERO, Vec3::NEG_Z));
/// # schedule.run(&mut world);
/// let mut culler = HierarchyCuller::default();
/// let camera = *world.resource::<Camera>();
/// let culled = culler.cull(&CullScene::new(&world), &camera);
/// assert!(culled.kept().count() <= culled.stats.after_frustum);
/// ```
#[derive(Debug, Default)]
pub struct HierarchyCuller {
    /// How it culls; change it between frames (a new leaf size builds the tree again).
    pub settings: HierarchySettings,
    bvh: Option<Bvh>,
    built_with: u32,
    /// The store's generation and layout generation the tree was last brought to.
    synced: Option<(u64, u64)>,
    frustum_visible: VisibleSet,
    kept: VisibleSet,
    pyramid: DepthPyramid,
    /// Skips occlusion where it has removed too little lately.
    gate: BenefitGate,
}

impl HierarchyCuller {
    /// The hierarchy with `settings`.
    pub fn new(settings: HierarchySettings) -> Self {
        Self { settings, ..Self::default() }
    }

    /// The tree, once a frame has built it.
    pub fn bvh(&self) -> Option<&Bvh> {
        self.bvh.as_ref()
    }

    /// Builds or refits the tree to the store.
    fn sync(&mut self, scene: &CullScene) {
        let store = scene.store();
        let change = if self.built_with == self.settings.leaf_size {
            scene.change_since(self.synced)
        } else {
            StoreChange::Layout
        };
        match (change, &mut self.bvh) {
            (StoreChange::None, Some(_)) => {}
            (StoreChange::Moved(listed), Some(bvh)) => {
                let moved = listed.map_or_else(|| bvh.changed_slots(store), <[u32]>::to_vec);
                bvh.refit(store, &moved);
            }
            _ => {
                self.bvh = Some(Bvh::build(store, self.settings.leaf_size));
                self.built_with = self.settings.leaf_size;
            }
        }
        self.synced = Some(scene.generations());
    }
}

impl Culler for HierarchyCuller {
    fn name(&self) -> String {
        "hierarchy".into()
    }

    fn is_conservative(&self, viewport: (u32, u32)) -> bool {
        self.settings.occlusion.is_conservative_for(viewport)
    }

    fn cull(&mut self, scene: &CullScene, camera: &Camera) -> Culled<'_> {
        let start = Instant::now();
        let store = scene.store();
        let mut stats = ViewStats { objects: store.len(), ..ViewStats::default() };
        let stage = Stage::Frustum.enter();
        self.sync(scene);
        let Some(frustum) = frustum_or_keep_everything(
            camera,
            store.len(),
            &mut self.frustum_visible,
            &mut self.kept,
            &mut stats,
            start,
        ) else {
            return Culled { stages: vec![("frustum", &self.frustum_visible), ("occlusion", &self.kept)], stats };
        };
        let bvh = self.bvh.as_ref().expect("sync builds the tree");
        let all_planes = ((1u32 << frustum.planes().len()) - 1) as u8;
        let (frustum_visible, kept) = (SharedVisibleSet::new(store.len()), SharedVisibleSet::new(store.len()));
        let traversal = Traversal {
            bvh,
            frustum: &frustum,
            occlusion: None,
            eye: camera.position,
            frustum_visible: &frustum_visible,
            kept: &kept,
            frustum_only: None,
        };
        traversal.run(all_planes);
        frustum_visible.copy_to(store.len(), &mut self.frustum_visible);
        stats.after_frustum = self.frustum_visible.count();
        stats.frustum_time = start.elapsed();
        drop(stage);

        let occlusion = self.settings.occlusion;
        let mut kept_set = &self.frustum_visible;
        let runs = occlusion.enabled && occlusion.validate().is_ok() && !bvh.nodes.is_empty();
        stats.occlusion_gated = runs && self.gate.skip_this_frame();
        if runs && !stats.occlusion_gated {
            let start = Instant::now();
            let stage = Stage::Raster.enter();
            let view = occlusion.view(camera);
            let occluders = scene.occluders_among(&self.frustum_visible, camera.position, occlusion.triangle_budget);
            let raster = rasterize(&view, &occluders, occlusion.mode, &mut self.pyramid);
            drop(stage);
            (stats.occluders, stats.occluder_triangles) = (occluders.len(), raster.triangles_rasterized);
            stats.occluders_hidden = raster.occluders_hidden;
            stats.raster_time = start.elapsed();
            let start = Instant::now();
            if self.pyramid.level_count() > 0 {
                let traversal = Traversal {
                    occlusion: Some((&view, &self.pyramid)),
                    frustum_only: Some(&self.frustum_visible),
                    ..traversal
                };
                let _stage = Stage::Occlusion.enter();
                traversal.run(all_planes);
                kept.copy_to(store.len(), &mut self.kept);
                kept_set = &self.kept;
            }
            stats.occlusion_time = start.elapsed();
            // A frame without occluders says nothing of what occlusion is worth here.
            if !occluders.is_empty() {
                let removed = stats.after_frustum - kept_set.count();
                self.gate.record_occlusion(removed, stats.after_frustum, &self.settings.adaptive);
            }
        }
        stats.after_occlusion = kept_set.count();
        let mut stages = vec![("frustum", &self.frustum_visible)];
        if occlusion.enabled {
            stages.push(("occlusion", kept_set));
        }
        Culled { stages, stats }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bounds::{LocalBounds, WorldBounds};
    use bevy_ecs::entity::Entity;
    use glam::Affine3A;

    fn store_of(boxes: &[(Vec3, Vec3)]) -> BoundsStore {
        let mut store = BoundsStore::default();
        for (i, &(center, half_extent)) in boxes.iter().enumerate() {
            let entity = Entity::from_raw_u32(i as u32 + 1).unwrap();
            let local = LocalBounds { center: Vec3::ZERO, half_extent };
            let bounds = WorldBounds::from_local(entity, &local, &Affine3A::from_translation(center)).unwrap();
            store.insert(entity, &bounds).unwrap();
        }
        store
    }

    fn boxes(count: usize) -> Vec<(Vec3, Vec3)> {
        (0..count)
            .map(|i| {
                let f = i as f32;
                let center = Vec3::new((f * 7.31).sin() * 300.0, (f * 1.7).cos() * 20.0, (f * 3.13).cos() * 300.0);
                (center, Vec3::new(0.5 + (f * 0.37).sin().abs() * 4.0, 1.0, 0.5 + (f * 0.91).cos().abs() * 4.0))
            })
            .collect()
    }

    /// Every slot is in one leaf, every node's box holds its objects' and its children's, and the node count is
    /// the one the layout reserves.
    fn assert_valid(bvh: &Bvh, store: &BoundsStore, leaf: u32) {
        let mut seen = vec![0; store.len()];
        for (index, node) in bvh.nodes.iter().enumerate() {
            let slots = &bvh.order[node.first as usize..][..node.count as usize];
            for &slot in slots {
                let (min, max) = slot_box(store, slot as usize);
                assert!(node.min.cmple(min).all() && node.max.cmpge(max).all(), "node {index} misses slot {slot}");
            }
            if node.right == LEAF {
                assert!(node.count <= leaf);
                slots.iter().for_each(|&s| seen[s as usize] += 1);
            } else {
                let (left, right) = (bvh.nodes[index + 1], bvh.nodes[node.right as usize]);
                assert_eq!(left.count + right.count, node.count);
                assert_eq!((left.first, right.first), (node.first, node.first + left.count));
            }
        }
        assert!(seen.iter().all(|&n| n == 1));
        let expected = if store.is_empty() { 0 } else { node_counts(store.len() as u32, leaf).0 };
        assert_eq!(bvh.nodes.len() as u32, expected);
    }

    #[test]
    fn the_tree_holds_every_object_once_after_building_and_refitting() {
        for count in [0, 1, 7, 8, 9, 100, 20_000] {
            let mut boxes = boxes(count);
            let mut store = store_of(&boxes);
            for leaf in [1, 4, 8] {
                assert_valid(&Bvh::build(&store, leaf), &store, leaf);
            }
            let mut bvh = Bvh::build(&store, 8);
            let moved: Vec<u32> = (0..count as u32).step_by(5).collect();
            for &slot in &moved {
                boxes[slot as usize].0 += Vec3::new(50.0, -3.0, slot as f32);
                let entity = Entity::from_raw_u32(slot + 1).unwrap();
                let local = LocalBounds { center: Vec3::ZERO, half_extent: boxes[slot as usize].1 };
                let bounds =
                    WorldBounds::from_local(entity, &local, &Affine3A::from_translation(boxes[slot as usize].0));
                store.set(slot as usize, &bounds.unwrap()).unwrap();
            }
            assert_eq!(bvh.changed_slots(&store), moved);
            bvh.refit(&store, &moved);
            assert_valid(&bvh, &store, 8);
        }
    }

    #[test]
    fn node_counts_match_the_layout_of_halving() {
        fn counted(count: u32, leaf: u32) -> u32 {
            if count <= leaf { 1 } else { 1 + counted(count / 2, leaf) + counted(count - count / 2, leaf) }
        }
        for leaf in [1, 3, 8] {
            for count in 0..300 {
                assert_eq!(
                    node_counts(count, leaf),
                    (counted(count, leaf), counted(count + 1, leaf)),
                    "{count} {leaf}"
                );
            }
        }
    }
}
