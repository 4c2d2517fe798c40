// Blend of the two reference-view passes into the final image. Mirrors crate::cpu::blend.

struct FullOut {
    @builtin(position) pos: vec4<f32>,
};

@vertex
fn vs_full(@builtin(vertex_index) i: u32) -> FullOut {
    let x = f32((i << 1u) & 2u) * 2.0 - 1.0;
    let y = f32(i & 2u) * 2.0 - 1.0;
    var out: FullOut;
    out.pos = vec4<f32>(x, y, 0.0, 1.0);
    return out;
}

// Blend of the two view passes. Each pass's alpha is 0 for a hole, else the distance to the
// camera. Weights w_i are scaled by exp(-SHARPNESS (d_i / d_min - 1)): where the two views see
// surfaces at clearly different distances the nearer wins (the farther one shows through a
// disocclusion the other view can fill), where they agree they blend. At a reference sample
// the other weight is 0, so the sample's own view stays exact. Where every weighted view is a
// hole, any covered view fills (never black where something exists).
const SHARPNESS: f32 = 20.0;

struct Blend {
    weights: vec4<f32>,  // w0, w1, number of views, unused
};
@group(0) @binding(0) var<uniform> blend: Blend;
@group(0) @binding(1) var view0: texture_2d<f32>;
@group(0) @binding(2) var view1: texture_2d<f32>;

@fragment
fn fs_blend(in: FullOut) -> @location(0) vec4<f32> {
    let p = vec2<i32>(in.pos.xy);
    let a = textureLoad(view0, p, 0);
    var b = vec4<f32>(0.0);
    if blend.weights.z > 1.5 {
        b = textureLoad(view1, p, 0);
    }
    let ca = select(0.0, 1.0, a.a > 0.0);
    let cb = select(0.0, 1.0, b.a > 0.0);
    if ca + cb == 0.0 {
        return vec4<f32>(0.0);
    }
    var dmin = max(a.a, b.a);
    if ca > 0.0 { dmin = min(dmin, a.a); }
    if cb > 0.0 { dmin = min(dmin, b.a); }
    let na = ca * exp(max(-80.0, -SHARPNESS * (a.a / dmin - 1.0)));
    let nb = cb * exp(max(-80.0, -SHARPNESS * (b.a / dmin - 1.0)));
    let wa = blend.weights.x * na;
    let wb = blend.weights.y * nb;
    if wa + wb > 0.0 {
        return vec4<f32>((a.rgb * wa + b.rgb * wb) / (wa + wb), 1.0);
    }
    return vec4<f32>((a.rgb * ca + b.rgb * cb) / (ca + cb), 1.0);
}
