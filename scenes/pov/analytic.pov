// Analytic test scene for `railview import-pov` (prerender/tests/pov.rs recomputes every
// distance from the numbers below; keep them in sync).
// POV-Ray frame: y up, left-handed. railview (x, y, z) = POV-Ray (x, y, -z).
// This file is part of railview (MIT OR Apache-2.0).

#version 3.7;
global_settings { assumed_gamma 1.0 }

light_source { <20, 30, -10> rgb 1 }

// The sky: rays that hit nothing get depth +inf.
sky_sphere {
  pigment { gradient y color_map { [0 rgb <0.75, 0.85, 1.0>] [1 rgb <0.2, 0.3, 0.8>] } }
}

// Ground plane y = 0 (a solid: everything below it is inside).
plane { y, 0 pigment { checker rgb 0.8 rgb 0.45 scale 2 } }

// Opaque spheres.
sphere { <0, 1, 6>, 1 pigment { rgb <0.9, 0.2, 0.2> } }
sphere { <-4, 1.5, -3>, 1.5 pigment { rgb <0.2, 0.8, 0.3> } }

// Axis-aligned box.
box { <3, 0, -2>, <5, 2.5, 1> pigment { rgb <0.2, 0.3, 0.9> } }

// Transparent surface: the colour shows what is behind it, the depth is its own surface.
sphere { <-2, 1, 2>, 0.8 pigment { rgbt <1, 1, 1, 0.8> } }
