//! The components that make an entity cullable, and their validation: every box the store holds passed
//! [`WorldBounds::from_local`] or [`WorldBounds::new`], so it is finite, has non-negative extents and a radius
//! that contains it.

use bevy_ecs::prelude::*;
use glam::{Affine3A, Vec3, Vec3A};
use thiserror::Error;

/// Relative rounding slack added to world bounds: 8 half-ulps (`8 * 2^-24`), twice the error bound of the
/// four rounded operations per axis that transform a box.
const BOUNDS_SLACK: f32 = 4.0 * f32::EPSILON;

/// An object's axis-aligned bounding box in its local space, as centre and half-extent.
///
/// Attach it with an [`ObjectTransform`] to make an entity cullable.
#[derive(Component, Clone, Copy, Debug, PartialEq)]
pub struct LocalBounds {
    /// Centre of the box in local space.
    pub center: Vec3,
    /// Half the size of the box along each local axis; each component must be finite and non-negative.
    pub half_extent: Vec3,
}

impl LocalBounds {
    /// The box spanning `min..=max`.
    pub fn from_min_max(min: Vec3, max: Vec3) -> Self {
        Self { center: (min + max) * 0.5, half_extent: (max - min) * 0.5 }
    }

    /// The smallest box around `points`, or `None` for no points.
    pub fn from_points(points: &[Vec3]) -> Option<Self> {
        let first = *points.first()?;
        let (min, max) = points.iter().fold((first, first), |(lo, hi), &p| (lo.min(p), hi.max(p)));
        Some(Self::from_min_max(min, max))
    }
}

/// The object's placement in the world.
///
/// A glam [`Affine3A`] (rotation, scale and shear plus translation) rather than Bevy's `Transform`: culling needs
/// only the matrix, and `Affine3A` is the SIMD-aligned form glam transforms points and boxes with fastest. The
/// engine has no hierarchy: give it the final world transform.
#[derive(Component, Clone, Copy, Debug, PartialEq)]
pub struct ObjectTransform(pub Affine3A);

/// The largest length a unit vector of an object's space takes in the world under `transform`: its longest
/// column, exact for a transform without shear. What scales a length of the mesh (a bounding sphere's radius,
/// a level of detail's error) into the world.
pub fn largest_axis_scale(transform: &Affine3A) -> f32 {
    let m = transform.matrix3;
    m.x_axis.length().max(m.y_axis.length()).max(m.z_axis.length())
}

/// Marks an object that never moves: bounds stage ([`crate::pipeline::CullStage::Bounds`]) never scans it, and later stages skip per-frame work for
/// it. To move a static object anyway, insert a new [`ObjectTransform`] (an insert, not a mutation).
#[derive(Component, Clone, Copy, Debug, Default)]
pub struct Static;

/// Inserted on an entity whose bounds were rejected, with the reason. The entity is not in the store, so no
/// stage culls or draws it; the error was also logged and kept for [`super::BoundsStore::take_errors`].
#[derive(Component, Clone, Debug, PartialEq)]
pub struct BoundsRejected(pub BoundsError);

/// Why an object's bounds were refused.
#[derive(Error, Clone, Copy, Debug, PartialEq)]
#[non_exhaustive]
pub enum BoundsError {
    /// The local box has a NaN or infinite coordinate.
    #[error("entity {entity}: local bounds are not finite (center {center}, half extent {half_extent})")]
    NonFiniteLocal {
        /// The offending entity.
        entity: Entity,
        /// Its local centre.
        center: Vec3,
        /// Its local half-extent.
        half_extent: Vec3,
    },
    /// A half-extent is negative.
    #[error("entity {entity}: local bounds have a negative half extent {half_extent}")]
    NegativeExtent {
        /// The offending entity.
        entity: Entity,
        /// Its local half-extent.
        half_extent: Vec3,
    },
    /// The transform has a NaN or infinite entry.
    #[error("entity {entity}: transform is not finite")]
    NonFiniteTransform {
        /// The offending entity.
        entity: Entity,
    },
    /// The transformed box overflowed `f32`.
    #[error("entity {entity}: world bounds overflow f32 (transform or box too large)")]
    WorldOverflow {
        /// The offending entity.
        entity: Entity,
    },
    /// World bounds given directly ([`WorldBounds::new`], [`crate::BoundsStore::insert`]) are not finite, have
    /// a negative half-extent, or a radius too small to contain the box.
    #[error(
        "entity {entity}: world bounds are invalid (center {center}, half extent {half_extent}, radius {radius}): \
         they must be finite, with non-negative half extents and a radius containing the box"
    )]
    InvalidWorld {
        /// The offending entity.
        entity: Entity,
        /// The centre given.
        center: Vec3,
        /// The half-extent given.
        half_extent: Vec3,
        /// The radius given.
        radius: f32,
    },
    /// A store slot past the last stored object.
    #[error("store slot {slot} is out of range: {len} objects are stored")]
    SlotOutOfRange {
        /// The slot asked for.
        slot: usize,
        /// Objects stored.
        len: usize,
    },
}

/// A world-space box (centre, half-extent) and the radius of its circumscribed sphere.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WorldBounds {
    /// Centre in world space.
    pub center: Vec3,
    /// Half-extent along the world axes.
    pub half_extent: Vec3,
    /// Radius of the sphere around `center` that contains the box.
    pub radius: f32,
}

impl WorldBounds {
    /// Transforms a local box to a world AABB that is guaranteed to contain the exactly transformed box: the
    /// `f32` result is inflated by a bound on its own rounding error. Validates everything on the way in.
    pub fn from_local(entity: Entity, local: &LocalBounds, transform: &Affine3A) -> Result<Self, BoundsError> {
        if !local.center.is_finite() || !local.half_extent.is_finite() {
            return Err(BoundsError::NonFiniteLocal { entity, center: local.center, half_extent: local.half_extent });
        }
        if local.half_extent.cmplt(Vec3::ZERO).any() {
            return Err(BoundsError::NegativeExtent { entity, half_extent: local.half_extent });
        }
        if !transform.is_finite() {
            return Err(BoundsError::NonFiniteTransform { entity });
        }
        let m = transform.matrix3;
        let abs_m = glam::Mat3A::from_cols(m.x_axis.abs(), m.y_axis.abs(), m.z_axis.abs());
        let local_center = Vec3A::from(local.center);
        let center = m * local_center + transform.translation;
        let extent = abs_m * Vec3A::from(local.half_extent);
        // Magnitude of every term that was rounded, per axis: the slack covers each one's error.
        let magnitude = abs_m * local_center.abs() + transform.translation.abs() + extent;
        let half_extent = extent + magnitude * BOUNDS_SLACK;
        let radius = circumradius(half_extent) * (1.0 + BOUNDS_SLACK);
        if !center.is_finite() || !half_extent.is_finite() || !radius.is_finite() {
            return Err(BoundsError::WorldOverflow { entity });
        }
        Ok(Self { center: center.into(), half_extent: half_extent.into(), radius })
    }

    /// The box `center ± half_extent` with the radius of its circumscribed sphere, validated like
    /// [`WorldBounds::from_local`] validates its result. `entity` only names the object in the error.
    ///
    /// # Errors
    /// [`BoundsError::InvalidWorld`] for a NaN or infinite coordinate or a negative half-extent.
    ///
    /// # Example
    /// ```
    /// use bevy_ecs::entity::Entity;
    /// use cullet::bounds::WorldBounds;
    /// use glam::Vec3;
    ///
    /// let bounds = WorldBounds::new(Entity::PLACEHOLDER, Vec3::ZERO, Vec3::ONE).unwrap();
    /// assert!(bounds.radius >= Vec3::ONE.length());
    /// assert!(WorldBounds::new(Entity::PLACEHOLDER, Vec3::ZERO, Vec3::new(1.0, -1.0, 1.0)).is_err());
    /// ```
    pub fn new(entity: Entity, center: Vec3, half_extent: Vec3) -> Result<Self, BoundsError> {
        let radius = circumradius(Vec3A::from(half_extent)) * (1.0 + BOUNDS_SLACK);
        let bounds = Self { center, half_extent, radius };
        bounds.validate(entity)?;
        Ok(bounds)
    }

    /// Checks what every stored box must satisfy: a finite centre, finite non-negative half-extents, and a
    /// finite radius at least the box's circumradius (the frustum test culls by the sphere alone). Every write
    /// of the store calls it.
    ///
    /// # Errors
    /// [`BoundsError::InvalidWorld`] naming `entity` when any of those fails.
    pub fn validate(&self, entity: Entity) -> Result<(), BoundsError> {
        let valid = self.center.is_finite()
            && self.half_extent.is_finite()
            && self.half_extent.cmpge(Vec3::ZERO).all()
            && self.radius.is_finite()
            && self.radius >= circumradius(Vec3A::from(self.half_extent));
        if valid {
            Ok(())
        } else {
            Err(BoundsError::InvalidWorld {
                entity,
                center: self.center,
                half_extent: self.half_extent,
                radius: self.radius,
            })
        }
    }

    /// The smallest and largest corner of the box.
    pub fn min_max(&self) -> (Vec3, Vec3) {
        (self.center - self.half_extent, self.center + self.half_extent)
    }
}

/// The length of `half_extent`, scaled so that squaring cannot overflow for boxes near the top of the f32 range
/// (infinite for an infinite extent, NaN for NaN).
fn circumradius(half_extent: Vec3A) -> f32 {
    let largest = half_extent.max_element();
    if largest > 0.0 && largest.is_finite() {
        largest * (half_extent / largest).length()
    } else if largest > 0.0 || largest.is_nan() {
        largest
    } else {
        0.0
    }
}
