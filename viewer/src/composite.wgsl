// Composite of the reference-view passes into the final image; prepended with cube.wgsl.
// Mirrors crate::cpu::blend.
//
// Each view pass's alpha is 0 for a hole, else the distance to the camera. The two views are
// blended: weights w_i are scaled by exp(-SHARPNESS (d_i / d_min - 1)), so where the two views see
// surfaces at clearly different distances the nearer wins (the farther one shows through a
// disocclusion the other view can fill), where they agree they blend. At a reference sample
// the other weight is 0, so the sample's own view stays exact. Where every weighted view is a
// hole, any covered view fills (never black where something exists).
//
// The sky stays in the view passes (drawn after the meshes with a depth test, so the
// rasteriser skips covered blocks): software rasterisers such as llvmpipe run both sides of a
// per-pixel branch, so sampling it here only where a view left a pixel empty would cost two
// cube-map lookups on every pixel.
//
// Debug overlays tint the result by the tile that drew the pixel in the dominant view (the
// one with the larger blend weight there): slab colours, the visible-pixel heat map of the
// tile-visibility feedback, and the streaming highlight of recently loaded tiles; `holes`
// paints pixels no view covers magenta (opaque).

const OVERLAY_HIGHLIGHT: u32 = 1u;
const OVERLAY_HEAT: u32 = 2u;
const OVERLAY_SLABS: u32 = 4u;
const OVERLAY_HOLES: u32 = 8u;

struct Composite {
    weights: vec4<f32>,  // w0, w1, number of views, log2(1 + pixels) of the frame
    flags: vec4<u32>,    // overlay bits, tiles of view 0, tiles of view 1, unused
};
@group(0) @binding(0) var<uniform> comp: Composite;
@group(0) @binding(1) var color0: texture_2d<f32>;
@group(0) @binding(2) var color1: texture_2d<f32>;
@group(0) @binding(3) var ids0: texture_2d<u32>;
@group(0) @binding(4) var ids1: texture_2d<u32>;
// Per tile (`tile_texel`): the views' tile info (render.wgsl's `tile_info`) and visible-pixel
// counts.
@group(0) @binding(5) var info0: texture_2d<u32>;
@group(0) @binding(6) var info1: texture_2d<u32>;
@group(0) @binding(7) var counts0: texture_2d<u32>;
@group(0) @binding(8) var counts1: texture_2d<u32>;

fn slab_color(slab: u32) -> vec3<f32> {
    switch slab % 4u {
        case 0u: { return vec3<f32>(1.0, 0.1, 0.1); }
        case 1u: { return vec3<f32>(0.1, 1.0, 0.1); }
        case 2u: { return vec3<f32>(0.1, 0.3, 1.0); }
        default: { return vec3<f32>(1.0, 0.1, 1.0); }
    }
}

// Cold (few pixels) to hot (many): blue, green, yellow, red.
fn heat_color(t: f32) -> vec3<f32> {
    let x = clamp(t, 0.0, 1.0) * 3.0;
    if x < 1.0 {
        return mix(vec3<f32>(0.0, 0.0, 1.0), vec3<f32>(0.0, 1.0, 0.0), x);
    }
    if x < 2.0 {
        return mix(vec3<f32>(0.0, 1.0, 0.0), vec3<f32>(1.0, 1.0, 0.0), x - 1.0);
    }
    return mix(vec3<f32>(1.0, 1.0, 0.0), vec3<f32>(1.0, 0.0, 0.0), x - 2.0);
}

// Tint by tile `t` (index, not + 1) of a view's tile info and counts.
fn tint(rgb: vec3<f32>, info: vec4<u32>, count: u32) -> vec3<f32> {
    var c = rgb;
    let flags = comp.flags.x;
    if (flags & OVERLAY_SLABS) != 0u {
        c = mix(c, slab_color(info.w), 0.5);
    }
    if (flags & OVERLAY_HEAT) != 0u {
        c = mix(c, heat_color(log2(1.0 + f32(count)) / comp.weights.w), 0.6);
    }
    if (flags & OVERLAY_HIGHLIGHT) != 0u {
        let h = clamp(bitcast<f32>(info.z), 0.0, 1.0);
        c = mix(c, vec3<f32>(1.0, 0.8, 0.0), 0.6 * h);
    }
    return c;
}

// The blended colour of a pixel (alpha 0 = hole) and the two effective weights.
struct Blended {
    color: vec4<f32>,
    wa: f32,
    wb: f32,
};

fn blend_at(pos: vec2<f32>) -> Blended {
    let p = vec2<i32>(pos);
    let a = textureLoad(color0, p, 0);
    var b = vec4<f32>(0.0);
    if comp.weights.z > 1.5 {
        b = textureLoad(color1, p, 0);
    }
    var out: Blended;
    let ca = select(0.0, 1.0, a.a > 0.0);
    let cb = select(0.0, 1.0, b.a > 0.0);
    if ca + cb == 0.0 {
        out.color = vec4<f32>(0.0);
        out.wa = 0.0;
        out.wb = 0.0;
        return out;
    }
    var dmin = max(a.a, b.a);
    if ca > 0.0 { dmin = min(dmin, a.a); }
    if cb > 0.0 { dmin = min(dmin, b.a); }
    let na = ca * exp(max(-80.0, -SHARPNESS * (a.a / dmin - 1.0)));
    let nb = cb * exp(max(-80.0, -SHARPNESS * (b.a / dmin - 1.0)));
    var wa = comp.weights.x * na;
    var wb = comp.weights.y * nb;
    if wa + wb <= 0.0 {
        wa = ca;
        wb = cb;
    }
    out.color = vec4<f32>((a.rgb * wa + b.rgb * wb) / (wa + wb), 1.0);
    out.wa = wa;
    out.wb = wb;
    return out;
}

// The composite's colour and the reversed-Z depth of the nearer view's surface (NEAR_M /
// distance; the sky's SKY_DISTANCE gives less than render.wgsl's SKY_DEPTH, a hole 0), for
// the fill pass that follows (`fs_fill` in render.wgsl reads it as a fused frame's depth).
struct CompositeOut {
    @location(0) color: vec4<f32>,
    @builtin(frag_depth) depth: f32,
};

const NEAR_M: f32 = 0.01;

fn nearer_depth(pos: vec2<f32>) -> f32 {
    let p = vec2<i32>(pos);
    let a = textureLoad(color0, p, 0).a;
    var b = 0.0;
    if comp.weights.z > 1.5 {
        b = textureLoad(color1, p, 0).a;
    }
    let d = select(max(a, b), min(a, b), a > 0.0 && b > 0.0);
    return select(0.0, NEAR_M / d, d > 0.0);
}

// Without overlays: touches neither tile ids nor tile buffers.
@fragment
fn fs_composite(in: FullOut) -> CompositeOut {
    var out: CompositeOut;
    out.color = blend_at(in.pos.xy).color;
    out.depth = nearer_depth(in.pos.xy);
    return out;
}

@fragment
fn fs_composite_overlays(in: FullOut) -> CompositeOut {
    var out: CompositeOut;
    out.color = overlays_color(in);
    out.depth = nearer_depth(in.pos.xy);
    return out;
}

fn overlays_color(in: FullOut) -> vec4<f32> {
    let r = blend_at(in.pos.xy);
    if r.color.a == 0.0 {
        if (comp.flags.x & OVERLAY_HOLES) != 0u {
            return vec4<f32>(1.0, 0.0, 1.0, 1.0);
        }
        return r.color;
    }
    var rgb = r.color.rgb;
    let p = vec2<i32>(in.pos.xy);
    if (comp.flags.x & (OVERLAY_HIGHLIGHT | OVERLAY_HEAT | OVERLAY_SLABS)) != 0u {
        if r.wa >= r.wb {
            let t = textureLoad(ids0, p, 0).x;
            if t > 0u && t <= comp.flags.y {
                let at = tile_texel(t - 1u);
                rgb = tint(rgb, textureLoad(info0, at, 0), textureLoad(counts0, at, 0).x);
            }
        } else {
            let t = textureLoad(ids1, p, 0).x;
            if t > 0u && t <= comp.flags.z {
                let at = tile_texel(t - 1u);
                rgb = tint(rgb, textureLoad(info1, at, 0), textureLoad(counts1, at, 0).x);
            }
        }
    }
    return vec4<f32>(rgb, 1.0);
}
