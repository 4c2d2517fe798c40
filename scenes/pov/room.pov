// A closed room lit mostly by radiosity: one small light high in a corner, coloured walls
// that bleed onto each other, a pillar and a low wall in the middle. Small and quick to
// render; the radiosity tests of `railview import-pov` and `railview build` use it.
// POV-Ray frame: y up, left-handed. railview (x, y, z) = POV-Ray (x, y, -z).
// This file is part of railview (MIT OR Apache-2.0).

#version 3.7;
global_settings {
  assumed_gamma 1.0
  radiosity {
    pretrace_start 0.08
    pretrace_end 0.02
    count 60
    nearest_count 5
    error_bound 0.5
    recursion_limit 1
  }
}

light_source { <3.5, 2.8, 3.5> rgb 0.6 }

#declare Wall = finish { diffuse 0.8 ambient 0 };
// Floor, ceiling and walls of the room [-4, 4] x [0, 3] x [-4, 4], as one hollow box.
difference {
  box { <-4.2, -0.2, -4.2>, <4.2, 3.2, 4.2> }
  box { <-4, 0, -4>, <4, 3, 4> }
  pigment { rgb <0.85, 0.82, 0.75> }
  finish { Wall }
}
// A red wall and a blue wall, a little in front of the room's walls.
box { <-4, 0, -4>, <-3.9, 3, 4> pigment { rgb <0.8, 0.15, 0.1> } finish { Wall } }
box { <-4, 0, 3.9>, <4, 3, 4> pigment { rgb <0.1, 0.2, 0.8> } finish { Wall } }
// A pillar and a low wall that hide parts of the room from parts of the track.
cylinder { <0.5, 0, 1>, <0.5, 3, 1>, 0.3 pigment { rgb 0.7 } finish { Wall } }
box { <-2.5, 0, -1.5>, <-0.5, 1.2, -1.3> pigment { rgb <0.6, 0.7, 0.5> } finish { Wall } }
