//! Scenes written out for clients that draw them: [`glb`], the geometry a
//! browser client draws (psao serve --web).

pub mod glb;
