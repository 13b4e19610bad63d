//! The exact ground truth of light views: which shadow casters a light view needs.
//!
//! The definition is `cullet::frustum::views`' own: with `V` the light view's frustum and `C` the camera's,
//! a box `B` is needed when the region it shadows meets `V ∩ C`:
//! - a directional light travelling along `d`: some `p + t d`, `p` in `B`, `t >= 0`, lies in `V ∩ C`;
//! - a point light at `l`: some `l + s (p - l)`, `p` in `B`, `s >= 1`, lies in `V ∩ C`.
//!
//! Both are linear feasibility problems in four unknowns (`p` and `t`; or `s p` and `s`), decided here exactly
//! in f64: by one plane that the whole sweep lies outside of, by a point of the box inside `V ∩ C`, and
//! otherwise by enumerating the vertices of the feasible region. Nothing is sampled.
//!
//! A light view's occlusion (`cullet::culler::LightOcclusionSettings`) also drops casters hidden from the
//! light: [`light_view_false_negatives`] counts an object as needed only when, besides the above, it owns a
//! texel of the exact rendering from the light, at the shadow map's texel centres. The needed object, visible
//! from the light at a texel whose ray goes on into `V ∩ C`, meets both conditions, so the two together judge
//! at least as strictly as it.

use crate::half_spaces::{exact_half_spaces, half_spaces, moved};
use crate::judge::reference_objects;
use crate::render::render_light_view;
use bevy_ecs::world::World;
use cullet::frustum::LightSource;
use cullet::mesh::Mesh;
use cullet::pipeline::{LightViews, LightViewsVisible};
use cullet::{BoundsStore, Camera};
use glam::{DMat4, DVec3, DVec4};
use rayon::prelude::*;

/// A light, in the frame of the half-spaces it is tested with.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ExactLight {
    /// Light travelling along this direction (any length but zero).
    Directional(DVec3),
    /// A point light at this position.
    Point(DVec3),
}

/// Whether a light view needs the box `min..=max` as a shadow caster (the module's definition). `view` and
/// `receivers` are the half-spaces of `V` and `C`; they, the light and the box share one frame.
pub fn caster_needed(view: &[DVec4], receivers: &[DVec4], light: ExactLight, min: DVec3, max: DVec3) -> bool {
    let planes: Vec<DVec4> = view.iter().chain(receivers).map(|p| *p / p.truncate().length()).collect();
    let center = (min + max) * 0.5;
    let extent = (max - min) * 0.5;
    if planes.iter().all(|p| p.truncate().dot(center) + p.w >= 0.0) {
        return true; // The box itself reaches into V ∩ C.
    }
    // One plane the whole sweep stays outside of.
    let swept_outside = |p: &DVec4| {
        let farthest = p.truncate().dot(center) + p.truncate().abs().dot(extent) + p.w;
        farthest < 0.0
            && match light {
                ExactLight::Directional(d) => p.truncate().dot(d) <= 0.0,
                ExactLight::Point(l) => farthest <= p.truncate().dot(l) + p.w,
            }
    };
    if planes.iter().any(swept_outside) {
        return false;
    }
    // Constraints `a · z + b >= 0` on z = (p, t) or (s p, s).
    let mut constraints: Vec<(DVec4, f64)> = Vec::new();
    let big = 1e7 * (1.0 + min.abs().max_element().max(max.abs().max_element()));
    match light {
        ExactLight::Directional(d) => {
            let d = d.normalize();
            for axis in 0..3 {
                let unit = DVec4::from((DVec3::AXES[axis], 0.0));
                constraints.push((unit, -min[axis]));
                constraints.push((-unit, max[axis]));
            }
            constraints.push((DVec4::W, 0.0));
            constraints.push((-DVec4::W, big));
            for p in &planes {
                constraints.push((DVec4::from((p.truncate(), p.truncate().dot(d))), p.w));
            }
        }
        ExactLight::Point(l) => {
            for axis in 0..3 {
                let unit = DVec3::AXES[axis];
                constraints.push((DVec4::from((unit, -min[axis])), 0.0));
                constraints.push((DVec4::from((-unit, max[axis])), 0.0));
            }
            constraints.push((DVec4::W, -1.0));
            constraints.push((-DVec4::W, 1e6));
            // n · (l (1 - s) + u) + w >= 0.
            for p in &planes {
                let n = p.truncate();
                constraints.push((DVec4::from((n, -n.dot(l))), n.dot(l) + p.w));
            }
        }
    }
    has_vertex(&constraints)
}

/// For each light view the frame culled ([`LightViewsVisible`] of `world`, which has just run the culling
/// schedule with [`LightViews`]): how many stored objects it culled that it needs as casters, decided exactly.
/// Every count is 0 for a conservative engine.
///
/// An object is needed by a light view when [`caster_needed`] says its box's shadow can reach the camera's view
/// and it owns at least one texel of the exact rendering of every object (`meshes`, as
/// [`crate::judge::reference_objects`]) from that light ([`render_light_view`] at `size` x `size` texels, the
/// shadow map's resolution): an object owning no texel changes no texel of the map. The rendering is made only
/// for a view that culled some object whose box passes [`caster_needed`] (which only occlusion can cull).
pub fn light_view_false_negatives(world: &World, meshes: &[Mesh], size: u32) -> Vec<usize> {
    let (Some(results), Some(lights)) = (world.get_resource::<LightViewsVisible>(), world.get_resource::<LightViews>())
    else {
        return Vec::new();
    };
    let (store, camera) = (world.resource::<BoundsStore>(), world.resource::<Camera>());
    let origin = camera.position.as_dvec3();
    let receivers = exact_half_spaces(camera);
    let mut objects = None;
    results
        .0
        .iter()
        .map(|result| {
            let own = half_spaces(result.view.clip_from_relative, result.view.depth);
            let view = moved(&own, result.view.origin.as_dvec3(), origin);
            let light = match &lights.0[result.light] {
                LightSource::Sun { direction, .. } => ExactLight::Directional(direction.as_dvec3()),
                LightSource::Lamp { position, .. } => ExactLight::Point(position.as_dvec3() - origin),
            };
            let needed_boxes: Vec<usize> = (0..store.len())
                .into_par_iter()
                .filter(|&slot| !result.visible.contains(slot))
                .filter(|&slot| {
                    let bounds = store.get(slot).expect("slots below the store's length are stored");
                    let center = bounds.center.as_dvec3() - origin;
                    let extent = bounds.half_extent.as_dvec3();
                    caster_needed(&view, &receivers, light, center - extent, center + extent)
                })
                .collect();
            if needed_boxes.is_empty() {
                return 0;
            }
            let objects = objects.get_or_insert_with(|| reference_objects(world, meshes));
            let seen = render_light_view(&result.view, objects, size).visibility().visible;
            needed_boxes.into_iter().filter(|&slot| seen.contains(slot)).count()
        })
        .collect()
}

/// Whether the bounded region `a · z + b >= 0` (every constraint) has a point: it has one exactly when it has a
/// vertex, where four independent constraints are tight. A vertex passes within a relative `1e-9`.
fn has_vertex(constraints: &[(DVec4, f64)]) -> bool {
    let constraints: Vec<(DVec4, f64)> = constraints
        .iter()
        .map(|&(a, b)| {
            let scale = a.length().max(f64::MIN_POSITIVE);
            (a / scale, b / scale)
        })
        .collect();
    let count = constraints.len();
    for i in 0..count {
        for j in i + 1..count {
            for k in j + 1..count {
                for m in k + 1..count {
                    let rows = [constraints[i], constraints[j], constraints[k], constraints[m]];
                    let a = DMat4::from_cols(rows[0].0, rows[1].0, rows[2].0, rows[3].0).transpose();
                    if a.determinant().abs() < 1e-12 {
                        continue;
                    }
                    let z = a.inverse() * -DVec4::new(rows[0].1, rows[1].1, rows[2].1, rows[3].1);
                    let tolerance = 1e-9 * (1.0 + z.abs().max_element());
                    if z.is_finite() && constraints.iter().all(|&(a, b)| a.dot(z) + b >= -tolerance) {
                        return true;
                    }
                }
            }
        }
    }
    false
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A unit cube's half-spaces, centred at `center`.
    fn cube(center: DVec3, half: f64) -> Vec<DVec4> {
        DVec3::AXES
            .iter()
            .flat_map(|&axis| {
                [DVec4::from((axis, half - axis.dot(center))), DVec4::from((-axis, half + axis.dot(center)))]
            })
            .collect()
    }

    #[test]
    fn a_box_above_the_receivers_is_needed_when_its_shadow_falls_on_them() {
        let view = cube(DVec3::ZERO, 10.0);
        let receivers = cube(DVec3::new(0.0, -5.0, 0.0), 1.0);
        let down = ExactLight::Directional(DVec3::NEG_Y);
        let (min, max) = (DVec3::new(-0.5, 3.0, -0.5), DVec3::new(0.5, 4.0, 0.5));
        assert!(caster_needed(&view, &receivers, down, min, max));
        // Lit from the side, its shadow passes beside the receivers.
        let sideways = ExactLight::Directional(DVec3::X);
        assert!(!caster_needed(&view, &receivers, sideways, min, max));
        // Slanted so that only the sweep, not one plane, decides: the shadow misses by a corner.
        let slant = ExactLight::Directional(DVec3::new(1.0, -1.0, 0.0));
        // x + y is kept along the sweep: [-2.8, -2.6] passes above the receivers' corner at x + y = -3.
        let off = (DVec3::new(-5.0, 2.2, -0.5), DVec3::new(-4.9, 2.3, 0.5));
        assert!(!caster_needed(&view, &receivers, slant, off.0, off.1));
        let on = (DVec3::new(-5.0, 1.5, -0.5), DVec3::new(-4.9, 1.6, 0.5));
        assert!(caster_needed(&view, &receivers, slant, on.0, on.1));
    }

    #[test]
    fn a_point_light_shadows_what_lies_beyond_the_box() {
        let view = cube(DVec3::ZERO, 10.0);
        let receivers = cube(DVec3::new(0.0, -5.0, 0.0), 1.0);
        let lamp = ExactLight::Point(DVec3::new(0.0, 8.0, 0.0));
        let (min, max) = (DVec3::new(-0.5, 3.0, -0.5), DVec3::new(0.5, 4.0, 0.5));
        assert!(caster_needed(&view, &receivers, lamp, min, max));
        // Beside the lamp, its shadow goes sideways and down, away from the receivers.
        let beside = (DVec3::new(5.0, 7.5, -0.5), DVec3::new(6.0, 8.5, 0.5));
        assert!(!caster_needed(&view, &receivers, lamp, beside.0, beside.1));
        // Below the receivers, the light throws its shadow farther down, never onto them.
        let below = (DVec3::new(-0.5, -9.0, -0.5), DVec3::new(0.5, -8.0, 0.5));
        assert!(!caster_needed(&view, &receivers, lamp, below.0, below.1));
    }
}
