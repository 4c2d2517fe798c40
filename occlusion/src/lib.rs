//! occlusion (under construction)
