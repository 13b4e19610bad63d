//! Every mesh's levels in one flat list, with the tables selection reads.

use super::{LodError, LodLevel, MAX_LEVELS};
use crate::mesh::Mesh;
#[cfg(feature = "lod")]
use crate::scene::Scene;
use bevy_ecs::prelude::Resource;

/// One mesh's levels as selection reads them.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(crate) struct ChainTable {
    /// Index in [`LodLibrary::meshes`] of the full-detail level; the others follow it.
    pub first: u32,
    /// How many levels, at least 1.
    pub levels: u8,
    /// Each level's error, in the mesh's units, non-decreasing.
    pub error: [f32; MAX_LEVELS],
    /// Each level's triangle count, non-increasing.
    pub triangles: [u32; MAX_LEVELS],
}

impl ChainTable {
    /// The coarsest level whose error is at most `allowed`: the full-detail level where none is.
    #[inline]
    pub fn coarsest_within(&self, allowed: f32) -> u8 {
        let mut level = 0;
        for l in 1..self.levels {
            if self.error[l as usize] <= allowed {
                level = l;
            }
        }
        level
    }
}

/// The levels of a scene's meshes ([`crate::mesh::MeshRef`] indices are chains here): one flat mesh list
/// ([`LodLibrary::meshes`]), each chain's levels in a run, finest first; a resource of a world set up by
/// [`super::install`].
#[derive(Resource, Clone, Debug, Default)]
pub struct LodLibrary {
    meshes: Vec<Mesh>,
    pub(crate) chains: Vec<ChainTable>,
    errors: Vec<(u32, LodError)>,
}

impl LodLibrary {
    /// Levels for each of `meshes` ([`super::build_chain`], meshes in parallel). A mesh the simplifier
    /// must not read keeps itself as its only level, and the reason is in [`LodLibrary::errors`].
    #[cfg(feature = "lod")]
    pub fn build(meshes: &[Mesh], settings: &super::ChainSettings) -> Self {
        Self::build_with(meshes, &[], settings)
    }

    /// Levels for each of `scene`'s meshes: the levels the scene brings ([`Scene::given_levels`], their
    /// errors measured by [`super::given_chain`]), and for every other mesh levels built as
    /// [`LodLibrary::build`] does. Given levels left out, and meshes the simplifier must not read, are in
    /// [`LodLibrary::errors`].
    #[cfg(feature = "lod")]
    pub fn for_scene(scene: &Scene, settings: &super::ChainSettings) -> Self {
        Self::build_with(&scene.meshes, &scene.given_levels, settings)
    }

    #[cfg(feature = "lod")]
    fn build_with(meshes: &[Mesh], given: &[(u32, Vec<Mesh>)], settings: &super::ChainSettings) -> Self {
        use rayon::prelude::*;
        let mut given_of = vec![None; meshes.len()];
        for (mesh, levels) in given {
            if let Some(slot) = given_of.get_mut(*mesh as usize) {
                *slot = Some(levels.as_slice());
            }
        }
        let chains: Vec<_> = meshes
            .par_iter()
            .zip(given_of)
            .map(|(mesh, given)| match given {
                Some(levels) => super::given_chain(mesh, levels),
                None => match super::build_chain(mesh, settings) {
                    Ok(levels) => (levels, Vec::new()),
                    Err(error) => (vec![LodLevel { mesh: mesh.clone(), error: 0.0 }], vec![error]),
                },
            })
            .collect();
        let mut errors = Vec::new();
        let chains = chains
            .into_iter()
            .enumerate()
            .map(|(i, (levels, refused))| {
                errors.extend(refused.into_iter().map(|error| (i as u32, error)));
                levels
            })
            .collect();
        let mut library = Self::from_chains(chains).expect("built chains are ordered and within the level count");
        library.errors = errors;
        library
    }

    /// The library of levels given (a scene's own, such as glTF `MSFT_lod`): per mesh, its levels finest first,
    /// the first with error 0.
    ///
    /// # Errors
    /// [`LodError::LevelCount`] for a mesh with no level or more than [`MAX_LEVELS`],
    /// [`LodError::UnorderedLevels`] where errors are not 0 first, then non-decreasing and finite.
    pub fn from_chains(chains: Vec<Vec<LodLevel>>) -> Result<Self, LodError> {
        let mut library = Self::default();
        for levels in chains {
            if levels.is_empty() || levels.len() > MAX_LEVELS {
                return Err(LodError::LevelCount { levels: levels.len() });
            }
            let mut table =
                ChainTable { first: library.meshes.len() as u32, levels: levels.len() as u8, ..Default::default() };
            let mut previous = 0.0;
            for (l, level) in levels.into_iter().enumerate() {
                let ordered = level.error.is_finite() && level.error >= previous && (l > 0 || level.error == 0.0);
                if !ordered {
                    return Err(LodError::UnorderedLevels { level: l, error: level.error });
                }
                previous = level.error;
                table.error[l] = level.error;
                table.triangles[l] = level.mesh.triangle_count() as u32;
                library.meshes.push(level.mesh);
            }
            library.chains.push(table);
        }
        Ok(library)
    }

    /// Every level of every mesh: chain `c`'s level `l` is `meshes()[mesh_of(c, l)]`. Build the GPU culler
    /// from these.
    pub fn meshes(&self) -> &[Mesh] {
        &self.meshes
    }

    /// How many chains (the source meshes).
    pub fn chain_count(&self) -> usize {
        self.chains.len()
    }

    /// How many levels chain `chain` has (0 for no such chain).
    pub fn levels(&self, chain: u32) -> usize {
        self.chains.get(chain as usize).map_or(0, |c| c.levels as usize)
    }

    /// The index in [`LodLibrary::meshes`] of `chain`'s `level`, or `None` where there is no such level.
    pub fn mesh_of(&self, chain: u32, level: u8) -> Option<u32> {
        let table = self.chains.get(chain as usize)?;
        (level < table.levels).then_some(table.first + level as u32)
    }

    /// The geometric error of `chain`'s `level` in the mesh's units, or `None` where there is no such level.
    pub fn error(&self, chain: u32, level: u8) -> Option<f32> {
        let table = self.chains.get(chain as usize)?;
        (level < table.levels).then(|| table.error[level as usize])
    }

    /// The triangles of `chain`'s `level`, or `None` where there is no such level.
    pub fn triangles(&self, chain: u32, level: u8) -> Option<u32> {
        let table = self.chains.get(chain as usize)?;
        (level < table.levels).then(|| table.triangles[level as usize])
    }

    /// Why meshes have fewer levels than they could: each mesh `LodLibrary::build` (feature `lod`) could not
    /// simplify, and each level a scene gave that `LodLibrary::for_scene` left out, by mesh.
    pub fn errors(&self) -> &[(u32, LodError)] {
        &self.errors
    }
}
