//! Bevy's own frustum test (`bevy_camera`'s `Frustum::intersects_obb`) over a whole store's objects, the
//! reference the frustum and views benches compare Cullet with.

use bevy_camera::primitives::{Aabb, Frustum as BevyFrustum};
use cullet::VisibleSet;
use rayon::prelude::*;

/// Bevy's test over all objects, parallel the same way as Cullet's (64 objects a word, 4096 a task).
pub fn cull_bevy(objects: &[(Aabb, bevy_math::Affine3A)], frustum: &BevyFrustum, visible: &mut VisibleSet) -> usize {
    visible.reset(objects.len());
    visible
        .words_mut()
        .par_chunks_mut(64)
        .zip(objects.par_chunks(64 * 64))
        .map(|(words, objects)| {
            let mut count = 0;
            for (word, objects) in words.iter_mut().zip(objects.chunks(64)) {
                *word = 0;
                for (lane, (aabb, transform)) in objects.iter().enumerate() {
                    *word |= (frustum.intersects_obb(aabb, transform, true, true) as u64) << lane;
                }
                count += word.count_ones() as usize;
            }
            count
        })
        .sum()
}
