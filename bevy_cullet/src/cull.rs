//! Stages 2 to 5 for every Bevy camera, through a [`ViewCuller`] each: Cullet's frustum test, occluder raster
//! and occlusion test, then the survivors written to Bevy's `ViewVisibility` and `VisibleEntities`.

use crate::convert;
use crate::lights::{CameraLights, LightSources, keep_within_reach};
use crate::mirror::CulletStore;
use crate::{CulletSettings, NoCulletOcclusion};
use bevy_camera::primitives::{Aabb, Frustum as BevyFrustum, Sphere};
use bevy_camera::visibility::{
    InheritedVisibility, NoCpuCulling, NoFrustumCulling, RenderLayers, SetViewVisibility, ViewVisibility,
    VisibilityClass, VisibilityRange, VisibleEntities, VisibleEntityRanges,
};
use bevy_camera::{Camera, Projection};
use bevy_ecs::prelude::*;
use bevy_ecs::system::NonSendMarker;
use bevy_light::{DirectionalLight, NotShadowCaster, PointLight, SpotLight};
use bevy_math::UVec2;
use bevy_mesh::Mesh3d;
use bevy_transform::components::GlobalTransform;
use bevy_utils::Parallel;
use cullet::Occluder;
use cullet::culler::{
    LightViewVisible, OcclusionSettings, ViewCuller, ViewFrame, ViewSettings, ViewStats as CullStats,
};
use cullet::depth::DepthBuffer;
use cullet::frustum::{LightView, View};
use cullet::occluders::OccluderInstance;
use cullet::visible::{VisibleSet, set_slots};
use rayon::prelude::*;
use std::any::TypeId;
use std::time::{Duration, Instant};

/// Counts and times of one camera's last culled frame: Cullet's stages ([`cullet::culler::ViewStats`], which
/// it dereferences to), then the write of what they kept.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ViewStats {
    /// The frustum and occlusion stages' counts and times, over the mirrored entities.
    pub cull: CullStats,
    /// Entities made visible in this view, mirrored or not, after `InheritedVisibility`, `RenderLayers` and
    /// `VisibilityRange`.
    pub visible: usize,
    /// Time spent writing `ViewVisibility` and `VisibleEntities`.
    pub write_time: Duration,
    /// The camera's light views this frame (each cascade of a directional light, each face of a point light,
    /// each spot light's map), culled with it.
    pub light_views: usize,
    /// Shadow casters the light views keep, summed over the views, before Bevy's per-entity rules.
    pub light_casters: usize,
    /// Casters the light views' occlusion hid from their lights, summed (already left out of
    /// `light_casters`).
    pub light_occluded: usize,
    /// Light views whose occlusion was skipped this frame for removing too little lately.
    pub light_occlusion_gated: usize,
    /// Time spent on the light views' occlusion.
    pub light_occlusion_time: Duration,
}

impl std::ops::Deref for ViewStats {
    type Target = CullStats;

    fn deref(&self) -> &CullStats {
        &self.cull
    }
}

/// Cullet's state for one camera: its [`ViewCuller`] (the result, the occluder buffer it culled with) and its
/// stats. The plugin adds it to every `Camera`.
#[derive(Component, Default, Debug)]
pub struct CulletView {
    culler: ViewCuller,
    lights: CameraLights,
    stats: ViewStats,
}

impl CulletView {
    /// Counts and times of the last frame.
    pub fn stats(&self) -> &ViewStats {
        &self.stats
    }

    /// The occluder depth buffer of the last frame (`1/w` of the farthest occluder per texel, 0 for none);
    /// empty where occlusion did not run.
    pub fn depth(&self) -> &DepthBuffer {
        self.culler.depth()
    }

    /// Store slots ([`crate::CulletStore::store`]) kept by the frustum and occlusion stages, before Bevy's
    /// per-entity rules.
    pub fn kept(&self) -> &VisibleSet {
        self.culler.visible()
    }

    /// The camera's light views of the last frame that culled them, each with the store slots of the shadow
    /// casters it keeps, before Bevy's per-entity rules.
    pub fn light_views(&self) -> &[LightViewVisible] {
        &self.lights.views
    }

    /// What the light views' write reads.
    pub(crate) fn lights(&self) -> &CameraLights {
        &self.lights
    }
}

/// A camera as the culling system reads it.
type CameraItem<'a> = (
    Entity,
    &'a Camera,
    &'a GlobalTransform,
    &'a Projection,
    &'a BevyFrustum,
    Option<&'a RenderLayers>,
    &'a mut VisibleEntities,
    &'a mut CulletView,
    Has<NoCpuCulling>,
    Has<NoCulletOcclusion>,
);

/// What Bevy's per-entity rules read of a drawable entity.
type Drawable<'a> = (
    &'a InheritedVisibility,
    &'a mut ViewVisibility,
    Option<&'a VisibilityClass>,
    Option<&'a RenderLayers>,
    Has<VisibilityRange>,
);

/// Words of the kept set (64 store slots each) in one chunk of the write, which rayon hands out in runs. Not
/// tuned.
const WRITE_WORDS: usize = 16;

/// [`Drawable`] as a query yields it.
type DrawableItem<'a> =
    (&'a InheritedVisibility, Mut<'a, ViewVisibility>, Option<&'a VisibilityClass>, Option<&'a RenderLayers>, bool);

/// What one thread made visible: how many entities, and the entities of each visibility class, in the order
/// they were shown, with the stretch of each list every chunk of the write filled. The lists keep their
/// capacity from frame to frame, on the thread that fills them.
#[derive(Default)]
pub(crate) struct Shown {
    count: usize,
    /// Each class met and its entities: a few classes at most, so a list searched from the last one used.
    by_class: Vec<(TypeId, Vec<Entity>)>,
    /// Where in `by_class` the last entity went: nearly every entity shares one class (meshes).
    last: usize,
    /// The lists' lengths when the current chunk began.
    chunk_start: Vec<usize>,
    /// What each chunk added to the lists, in the order the chunks ran on this thread.
    stretches: Vec<Stretch>,
}

/// The entities one chunk of the write added to one of a thread's lists: `by_class[class].1[start..end]`.
#[derive(Clone, Copy)]
struct Stretch {
    chunk: usize,
    class: usize,
    start: usize,
    end: usize,
}

/// The chunk of the entities shown outside the kept set (after every chunk of it).
const OTHER_ENTITIES: usize = usize::MAX;

impl Shown {
    /// Queues `entity` for the camera's list of `class`.
    fn push(&mut self, entity: Entity, class: TypeId) {
        if self.by_class.get(self.last).is_none_or(|(last, _)| *last != class) {
            self.last = match self.by_class.iter().position(|(listed, _)| *listed == class) {
                Some(index) => index,
                None => {
                    self.by_class.push((class, Vec::new()));
                    self.by_class.len() - 1
                }
            };
        }
        self.by_class[self.last].1.push(entity);
    }

    /// Begins a chunk: what is queued until [`Shown::end_chunk`] belongs to it.
    fn begin_chunk(&mut self) {
        self.chunk_start.clear();
        self.chunk_start.extend(self.by_class.iter().map(|(_, list)| list.len()));
    }

    /// Records what was queued since [`Shown::begin_chunk`] as chunk `chunk`. A stretch that continues one of
    /// the same chunk and class recorded last extends it: the entities shown one by one outside the kept set
    /// ([`OTHER_ENTITIES`]) make one stretch per thread and class, however many they are.
    fn end_chunk(&mut self, chunk: usize) {
        for (class, (_, list)) in self.by_class.iter().enumerate() {
            let (start, end) = (self.chunk_start.get(class).copied().unwrap_or(0), list.len());
            if end == start {
                continue;
            }
            let mut same_chunk = self.stretches.iter_mut().rev().take_while(|stretch| stretch.chunk == chunk);
            match same_chunk.find(|stretch| (stretch.class, stretch.end) == (class, start)) {
                Some(stretch) => stretch.end = end,
                None => self.stretches.push(Stretch { chunk, class, start, end }),
            }
        }
    }
}

/// Entities the plugin mirrors (see [`crate::mirror`]).
type MirroredDrawable = (With<Aabb>, Without<NoFrustumCulling>, Without<NoCpuCulling>);
/// Entities Bevy's check would see that the plugin does not mirror.
type OtherDrawable = (Without<NoCpuCulling>, Or<(Without<Aabb>, With<NoFrustumCulling>)>);

/// The occlusion settings for a camera whose viewport is `viewport` pixels, where known. A pixel-centre or
/// masked buffer is conservative only for the frame it samples: it follows the viewport
/// ([`OcclusionSettings::resized_to`]); where the size is not known (no render target yet) the camera gets
/// the buffer that is conservative at any size, [`OcclusionSettings::default`]'s, with the same switch and
/// triangle budget.
fn occlusion_for(settings: OcclusionSettings, viewport: Option<UVec2>) -> OcclusionSettings {
    if !settings.mode.samples_pixel_centres() {
        return settings;
    }
    match viewport {
        Some(size) => settings.resized_to(size.x, size.y),
        None => OcclusionSettings {
            enabled: settings.enabled,
            triangle_budget: settings.triangle_budget,
            ..OcclusionSettings::default()
        },
    }
}

/// For every active camera: culls the mirrored objects, then writes the visible ones (and the entities Cullet
/// does not mirror, by Bevy's rules) into `ViewVisibility` and the camera's `VisibleEntities`, sorted.
#[allow(clippy::too_many_arguments, clippy::type_complexity)]
pub(crate) fn cull_views(
    cullet: Res<CulletStore>,
    settings: Res<CulletSettings>,
    mut cameras: Query<CameraItem>,
    mut drawables: ParamSet<(
        Query<(Entity, Drawable<'static>), MirroredDrawable>,
        Query<(Entity, Drawable<'static>, Option<&Sphere>), OtherDrawable>,
    )>,
    occluders: Query<(&Occluder, &GlobalTransform, Option<&InheritedVisibility>, Option<&RenderLayers>)>,
    changed_occluders: Query<
        (),
        (With<Occluder>, Or<(Changed<Occluder>, Changed<InheritedVisibility>, Changed<RenderLayers>)>),
    >,
    light_sources: LightSources,
    light_layers: Query<Option<&RenderLayers>, Or<(With<DirectionalLight>, With<PointLight>, With<SpotLight>)>>,
    casting_occluders: Query<
        (&Occluder, &GlobalTransform, &InheritedVisibility, Option<&RenderLayers>),
        (With<Mesh3d>, Without<NotShadowCaster>),
    >,
    ranges: Option<Res<VisibleEntityRanges>>,
    mut queues: Local<Parallel<Shown>>,
    mut order: Local<Vec<(usize, usize, usize)>>,
    // On the main thread: where the app made it one of rayon's (see the crate's "Threads"), each stage starts
    // there at once.
    _main_thread: NonSendMarker,
) {
    // Whether an occluder's mesh, visibility or layers changed: a scan of every occluder's change ticks, so asked
    // only for a camera whose view is the one it last culled: any other camera culls in full anyway.
    let mut occluders_changed = None;
    for (
        camera_entity,
        camera,
        transform,
        projection,
        bevy_frustum,
        layers,
        mut visible_entities,
        mut view,
        no_cpu_culling,
        no_occlusion,
    ) in &mut cameras
    {
        if !camera.is_active {
            continue;
        }
        let view_layers = layers.unwrap_or_default();
        let culled = convert::view_of(transform, projection);
        let mut occlusion = occlusion_for(settings.occlusion, camera.physical_viewport_size());
        occlusion.enabled &= !no_occlusion && !no_cpu_culling;
        let frame_settings = ViewSettings {
            frustum: settings.frustum && !no_cpu_culling,
            occlusion,
            adaptive: settings.adaptive,
            ..ViewSettings::default()
        };
        let view = &mut *view;
        let lights = &mut view.lights;
        lights.unculled.clear();
        let lit = if settings.lights {
            let (origin, receivers) = (convert::vec3(transform.translation()), culled.frustum.as_ref().ok());
            light_sources.views_of(camera_entity, origin, receivers, view_layers, bevy_frustum, &mut lights.unculled)
        } else {
            Vec::new()
        };
        let (maps, lit): (Vec<_>, Vec<LightView>) = lit.into_iter().unzip();
        let also: Vec<View> = lit.iter().map(|light| light.view.clone()).collect();
        let lights_changed = maps != lights.maps || lit.iter().ne(lights.views.iter().map(|culled| &culled.view));

        let same_view = view.culler.last_view() == Some(culled);
        let frame = ViewFrame {
            view: culled,
            settings: frame_settings,
            moves: cullet.moves.as_ref(),
            changed: lights_changed
                || (same_view && *occluders_changed.get_or_insert_with(|| !changed_occluders.is_empty())),
        };
        let mut sets = std::mem::take(&mut lights.spare);
        let light_kept = view.culler.cull_frustum(&cullet.store, &frame, &also, &mut sets);
        view.culler.cull_occlusion(&cullet.store, |slot| {
            let (occluder, transform, inherited, layers) = occluders.get(cullet.store.entities()[slot]).ok()?;
            let shown =
                inherited.is_none_or(|inherited| inherited.get()) && view_layers.intersects(layers.unwrap_or_default());
            shown.then(|| OccluderInstance { occluder, transform: convert::affine(transform) })
        });
        view.stats.cull = *view.culler.stats();
        let stats = &mut view.stats;
        match light_kept {
            Some(counts) => {
                let culled = lit.into_iter().zip(sets.drain(..also.len())).zip(counts).enumerate();
                let fresh = culled.map(|(index, ((view, visible), kept))| LightViewVisible {
                    light: index,
                    view,
                    visible,
                    kept,
                    occluded: 0,
                });
                let old = std::mem::replace(&mut lights.views, fresh.collect());
                sets.extend(old.into_iter().map(|view| view.visible));
                for (view, map) in lights.views.iter_mut().zip(&maps) {
                    if let Some(reach) = map.reach {
                        keep_within_reach(&cullet.store, view, reach);
                    }
                }
                // An occluder hides casters from a light only where it is drawn into that light's maps: a
                // visible shadow caster in the layers of every light culled here.
                let layers_of_lights: Vec<&RenderLayers> =
                    maps.iter().map(|map| light_layers.get(map.light).ok().flatten().unwrap_or_default()).collect();
                // The views of lights with `NoCulletLightCulling` come last, and are not occluded.
                let narrowed = maps.iter().take_while(|map| map.narrowed).count();
                let occluded = lights.occlusion.occlude(
                    &cullet.store,
                    &mut lights.views[..narrowed],
                    &settings.light_occlusion,
                    &settings.adaptive,
                    |slot| {
                        let entity = cullet.store.entities()[slot];
                        let (occluder, transform, inherited, layers) = casting_occluders.get(entity).ok()?;
                        let layers = layers.unwrap_or_default();
                        let drawn = inherited.get() && layers_of_lights.iter().all(|light| light.intersects(layers));
                        drawn.then(|| OccluderInstance { occluder, transform: convert::affine(transform) })
                    },
                );
                (stats.light_occluded, stats.light_occlusion_gated) = (occluded.occluded, occluded.gated);
                stats.light_occlusion_time = occluded.time;
                lights.maps = maps;
            }
            // Last frame's light views stand, with the camera's result.
            None if stats.cull.reused => {}
            // Not culled this frame (the stage is off, the camera has no frustum): every view keeps everything.
            None => {
                let every = |(index, view)| LightViewVisible {
                    light: index,
                    view,
                    visible: VisibleSet::all(cullet.store.len()),
                    kept: cullet.store.len(),
                    occluded: 0,
                };
                lights.views = lit.into_iter().enumerate().map(every).collect();
                lights.maps = maps;
                (stats.light_occluded, stats.light_occlusion_gated) = (0, 0);
                stats.light_occlusion_time = Duration::ZERO;
            }
        }
        lights.spare = sets;
        stats.light_views = lights.views.len() + lights.unculled.len();
        stats.light_casters = lights.views.iter().map(|view| view.kept).sum();

        let start = Instant::now();
        let in_range = |entity: Entity, has_range: bool| {
            !has_range || ranges.as_ref().is_none_or(|ranges| ranges.entity_is_in_range_of_view(entity, camera_entity))
        };
        // Bevy's per-entity rules, then the entity is made visible and queued for the camera's lists.
        let show = |shown: &mut Shown, entity: Entity, drawable: DrawableItem| {
            let (inherited, mut view_visibility, class, layers, has_range) = drawable;
            if inherited.get() && view_layers.intersects(layers.unwrap_or_default()) && in_range(entity, has_range) {
                view_visibility.set_visible();
                shown.count += 1;
                for &class in class.into_iter().flat_map(|class| class.iter()) {
                    shown.push(entity, class);
                }
            }
        };
        // Each kept entity looked up, in store order (entity order, so nearly table order), on rayon's threads:
        // Bevy's `par_iter_many_unique_mut` runs on one thread where its compute pool has one (2 cores).
        // Scanning every mirrored entity for the kept ones instead was slower at any share kept. The kept set's
        // words are split directly: collecting the kept entities first took a fifth of the write.
        let entities = cullet.store.entities();
        let mut mirrored = drawables.p0();
        view.culler.visible().words().par_chunks(WRITE_WORDS).enumerate().for_each_init(
            || queues.borrow_local_mut(),
            |queue, (chunk, words)| {
                queue.begin_chunk();
                let kept = set_slots(chunk * WRITE_WORDS, words).map(|slot| entities[slot]);
                // SAFETY: `iter_many_unsafe` may give two items the same entity's components: no chunk, and no
                // two chunks, hold an entity twice, as chunks hold distinct slots and the store holds each
                // entity in one slot at most. `mirrored` borrows the query exclusively (the `ParamSet`) until
                // every chunk is done, so nothing else reaches them.
                let mut items = unsafe { mirrored.iter_many_unsafe(kept) };
                while let Some(item) = items.fetch_next() {
                    // Kept entities without Bevy's visibility components (a bare occluder) show nothing.
                    if let Ok((entity, drawable)) = item {
                        show(queue, entity, drawable);
                    }
                }
                queue.end_chunk(chunk);
            },
        );
        // Entities whose bounds Cullet refused are visible everywhere (never in the store, so none was above).
        let mut rejected = mirrored.iter_many_mut(&cullet.rejected);
        let mut queue = queues.borrow_local_mut();
        queue.begin_chunk();
        while let Some(item) = rejected.fetch_next() {
            if let Ok((entity, drawable)) = item {
                show(&mut queue, entity, drawable);
            }
        }
        queue.end_chunk(OTHER_ENTITIES);
        drop(queue);
        // `settings.frustum` is off for a camera with `NoCpuCulling` (above).
        let frustum_culls = settings.frustum;
        drawables.p1().par_iter_mut().for_each_init(
            || queues.borrow_local_mut(),
            |queue, (entity, drawable, sphere)| {
                if !(frustum_culls && sphere.is_some_and(|sphere| !bevy_frustum.intersects_sphere(sphere, false))) {
                    queue.begin_chunk();
                    show(queue, entity, drawable);
                    queue.end_chunk(OTHER_ENTITIES);
                }
            },
        );
        // Each thread's lists joined stretch by stretch in chunk order: the kept entities in store order, then
        // the others. (The lists stay with the threads that fill them: lists handed to whichever thread ran a
        // chunk took a fifth longer to fill, their lines moving between cores.)
        visible_entities.clear_all();
        let mut shown: Vec<&mut Shown> = queues.iter_mut().collect();
        order.clear();
        for (thread, queue) in shown.iter().enumerate() {
            order.extend(queue.stretches.iter().enumerate().map(|(index, stretch)| (stretch.chunk, thread, index)));
        }
        order.sort_unstable();
        for &(_, thread, index) in order.iter() {
            let Stretch { class, start, end, .. } = shown[thread].stretches[index];
            let (class, list) = &shown[thread].by_class[class];
            visible_entities.get_mut(*class).extend_from_slice(&list[start..end]);
        }
        let mut visible = 0;
        for queue in &mut shown {
            visible += std::mem::take(&mut queue.count);
            queue.stretches.clear();
            queue.by_class.iter_mut().for_each(|(_, list)| list.clear());
        }
        // Bevy's renderer diffs these lists in O(n), which needs them sorted. In store order they already are
        // where the store holds its entities in their order (as the mirror leaves entities spawned together,
        // until a despawn moves the last one into a hole); telling costs a read of each list, sorting them anyway
        // far more. Otherwise they are long sorted runs, which the stable sort merges.
        for list in visible_entities.entities.values_mut().filter(|list| !list.is_sorted()) {
            list.sort();
        }
        view.stats.visible = visible;
        view.stats.write_time = start.elapsed();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Chunks of the kept set make a stretch each; entities shown one by one outside it, of two classes in
    /// turn, make one per class.
    #[test]
    fn stretches_of_one_chunk_and_class_are_joined() {
        let (meshes, sprites) = (TypeId::of::<u8>(), TypeId::of::<u16>());
        let entity = |i: u32| Entity::from_raw_u32(i).unwrap();
        let mut shown = Shown::default();
        for chunk in 0..2 {
            shown.begin_chunk();
            shown.push(entity(chunk + 1), meshes);
            shown.push(entity(chunk + 10), meshes);
            shown.end_chunk(chunk as usize);
        }
        for i in 20..30 {
            shown.begin_chunk();
            shown.push(entity(i), if i % 2 == 0 { meshes } else { sprites });
            shown.end_chunk(OTHER_ENTITIES);
        }
        let stretches: Vec<_> = shown.stretches.iter().map(|s| (s.chunk, s.class, s.start, s.end)).collect();
        assert_eq!(stretches, [(0, 0, 0, 2), (1, 0, 2, 4), (OTHER_ENTITIES, 0, 4, 9), (OTHER_ENTITIES, 1, 0, 5)]);
    }
}
