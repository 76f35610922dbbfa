#version 330 core
// pgt-check: head-light shading for colourless meshes in the pyrender backend. Replaces
// pyrender's flat.frag (used with RenderFlags.FLAT) and computes exactly what the moderngl
// backend computes: shade = ambient + (1 - ambient) * |n . v| with the per-face normal n (from
// screen-space derivatives, independent of winding) and the unit view ray v. The ambient term
// arrives in material.emissive_factor.r (a uniform pyrender always sets; unused otherwise).
struct Material {
    vec3 emissive_factor;
};
uniform Material material;
uniform vec3 cam_pos;

in vec3 frag_position;

out vec4 frag_color;

void main()
{
    vec3 n = normalize(cross(dFdx(frag_position), dFdy(frag_position)));
    float ambient = material.emissive_factor.r;
    float s = ambient + (1.0 - ambient) * abs(dot(n, normalize(cam_pos - frag_position)));
    frag_color = vec4(vec3(clamp(s, 0.0, 1.0)), 1.0);
}
