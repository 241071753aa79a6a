//! `bounce-types`: the leaf vocabulary every other crate speaks. Lights and light sets with their
//! validation (`light`), the spherical-harmonic basis a sky is given in (`sh`) and the six face
//! directions of a patch (`face`). Nothing here knows about
//! scenes, bakes, matrices or transports: that is `bounce-core`, which re-exports these modules,
//! so a thin client can name a light or a face without building the bake.

pub mod face;
pub mod light;
pub mod sh;
