// How the page shades a surface, kept equal to the native renderer's (render/src/shade.wgsl):
// diffuse only (radiance = albedo/π · E + emission/π), E = direct light with shadow maps + the
// indirect irradiance sampled from the six-direction volume, Reinhard tonemap after exposure.
//
// three.js does the direct part: MeshLambertMaterial is per-fragment Lambert with physical light
// units (point and spot in candela, directional in lux, glTF's inverse-square falloff with the
// range window), which is KHR_lights_punctual and so bounce_core::direct. Three things are patched
// into its shader: the indirect irradiance is added where three adds ambient light, the spot cone
// uses glTF's squared linear falloff instead of three's smoothstep, and the shadow lookup is
// offset to the side of the surface that faces the light. The shadow maps are drawn with the
// native renderer's slope-scaled depth bias.

import { Color, DoubleSide, MeshDepthMaterial, MeshDistanceMaterial, MeshLambertMaterial, Vector3 } from 'three';

// The uniforms every converted material shares: one object, so updating it updates them all.
export function volumeUniforms() {
  return {
    bounceVolPX: { value: null },
    bounceVolNX: { value: null },
    bounceVolPY: { value: null },
    bounceVolNY: { value: null },
    bounceVolPZ: { value: null },
    bounceVolNZ: { value: null },
    bounceSeparators: { value: null },
    bounceOrigin: { value: new Vector3() },
    bounceVoxelSize: { value: 1 },
    bounceDims: { value: new Vector3(1, 1, 1) },
    // 1: add the indirect light; 0: leave it out (the "direct only" toggle, or no frame yet).
    bounceIndirect: { value: 0 },
  };
}

export function bindVolume(uniforms, volume) {
  const [px, nx, py, ny, pz, nz] = volume.textures;
  uniforms.bounceVolPX.value = px;
  uniforms.bounceVolNX.value = nx;
  uniforms.bounceVolPY.value = py;
  uniforms.bounceVolNY.value = ny;
  uniforms.bounceVolPZ.value = pz;
  uniforms.bounceVolNZ.value = nz;
  uniforms.bounceSeparators.value = volume.separatorTexture;
  uniforms.bounceOrigin.value.fromArray(volume.origin);
  uniforms.bounceVoxelSize.value = volume.voxelSize;
  uniforms.bounceDims.value.fromArray(volume.dims);
}

const VERTEX_DECL = /* glsl */ `
varying vec3 vBounceWorld;
// The normal turned to the side of the surface that faces the light, given the vector from the
// light to the surface: what the shadow lookup offsets along (see installShadowOffset).
vec3 bounceTowardLight(vec3 n, vec3 lightToSurface) {
  return dot(n, lightToSurface) > 0.0 ? -n : n;
}
void main() {`;

const VERTEX_WORLD = /* glsl */ `#include <project_vertex>
  vBounceWorld = (modelMatrix * vec4(transformed, 1.0)).xyz;`;

// The twin of shade.wgsl's volume_texel, dominant_face and sample_volume.
const FRAGMENT_DECL = /* glsl */ `
uniform highp sampler3D bounceVolPX;
uniform highp sampler3D bounceVolNX;
uniform highp sampler3D bounceVolPY;
uniform highp sampler3D bounceVolNY;
uniform highp sampler3D bounceVolPZ;
uniform highp sampler3D bounceVolNZ;
uniform highp sampler3D bounceSeparators;
uniform vec3 bounceOrigin;
uniform float bounceVoxelSize;
uniform vec3 bounceDims;
uniform float bounceIndirect;
varying vec3 vBounceWorld;

vec4 bounceTexel(int face, ivec3 t) {
  if (face == 0) return texelFetch(bounceVolPX, t, 0);
  if (face == 1) return texelFetch(bounceVolNX, t, 0);
  if (face == 2) return texelFetch(bounceVolPY, t, 0);
  if (face == 3) return texelFetch(bounceVolNY, t, 0);
  if (face == 4) return texelFetch(bounceVolPZ, t, 0);
  return texelFetch(bounceVolNZ, t, 0);
}

int bounceDominantFace(vec3 n) {
  vec3 a = abs(n);
  if (a.x >= a.y && a.x >= a.z) return n.x >= 0.0 ? 0 : 1;
  if (a.y >= a.z) return n.y >= 0.0 ? 2 : 3;
  return n.z >= 0.0 ? 4 : 5;
}

vec3 bounceSampleVolume(vec3 p, vec3 n) {
  if (!(dot(n, n) > 0.0)) return vec3(0.0);
  int face = bounceDominantFace(n);
  vec3 u = (p - bounceOrigin) / bounceVoxelSize - 0.5;
  ivec3 maxT = ivec3(bounceDims) - 1;
  vec3 fl = floor(u);
  ivec3 lo = ivec3(clamp(fl, vec3(-1.0), vec3(maxT) + 1.0));
  vec3 fr = clamp(u - fl, 0.0, 1.0);
  ivec3 own = ivec3(greaterThanEqual(fr, vec3(0.5)));
  int separated = int(texelFetch(bounceSeparators, clamp(lo + own, ivec3(0), maxT), 0).r * 255.0 + 0.5);
  vec4 acc = vec4(0.0);
  for (int corner = 0; corner < 8; corner++) {
    ivec3 st = ivec3(corner & 1, (corner >> 1) & 1, (corner >> 2) & 1);
    bool blocked = false;
    for (int a = 0; a < 3; a++) {
      if (st[a] != own[a]) {
        int towards = 2 * a + (st[a] > own[a] ? 0 : 1);
        if (((separated >> towards) & 1) != 0) blocked = true;
      }
    }
    if (blocked) continue;
    vec3 w3 = mix(vec3(1.0) - fr, fr, vec3(st));
    float w = w3.x * w3.y * w3.z;
    if (w == 0.0) continue;
    acc += w * bounceTexel(face, clamp(lo + st, ivec3(0), maxT));
  }
  return acc.w >= ${(1 / 256).toFixed(8)} ? acc.rgb / acc.w : vec3(0.0);
}
void main() {`;

// The volume is read with the triangle's own normal turned to the seen side, as in shade.wgsl: the
// side whose patch (by the direction it faces most) holds this surface's light; `normal`, the
// shading normal in view space, only where the triangle's is degenerate.
const FRAGMENT_INDIRECT = /* glsl */ `
vec3 bounceNormal = cross(dFdx(vBounceWorld), dFdy(vBounceWorld));
if (!(dot(bounceNormal, bounceNormal) > 0.0)) {
  bounceNormal = inverseTransformDirection(normal, viewMatrix);
}
if (dot(bounceNormal, cameraPosition - vBounceWorld) < 0.0) {
  bounceNormal = -bounceNormal;
}
if (bounceIndirect > 0.0) {
  irradiance += bounceSampleVolume(vBounceWorld, bounceNormal);
}
#include <lights_fragment_end>`;

const SPOT_THREE = 'return smoothstep( coneCosine, penumbraCosine, angleCosine );';
const SPOT_GLTF =
  'float a = clamp( ( angleCosine - coneCosine ) / max( penumbraCosine - coneCosine, 0.001 ), 0.0, 1.0 ); return a * a;';

// What both materials patch in: the shadow lookup's offset and glTF's spot falloff, and, given
// as `decl` and `indirect`, the fragment shader's declarations and its indirect term.
function patchShader(shader, uniforms, decl = FRAGMENT_DECL, indirect = FRAGMENT_INDIRECT) {
  Object.assign(shader.uniforms, uniforms);
  shader.vertexShader = shader.vertexShader
    .replace('void main() {', VERTEX_DECL)
    .replace('#include <project_vertex>', VERTEX_WORLD)
    .replace('#include <shadowmap_vertex>', THREE_SHADOWMAP_VERTEX_TOWARD_LIGHT);
  shader.fragmentShader = shader.fragmentShader
    .replace('void main() {', decl)
    .replace('#include <lights_fragment_end>', indirect)
    .replace('#include <lights_pars_begin>', THREE_LIGHTS_PARS_GLTF_SPOT);
}

let THREE_LIGHTS_PARS_GLTF_SPOT = '#include <lights_pars_begin>';

// Called once with three's ShaderChunk, so the spot falloff patch fails loudly if three changes.
export function installSpotFalloff(ShaderChunk) {
  const chunk = ShaderChunk.lights_pars_begin;
  if (!chunk.includes(SPOT_THREE)) {
    throw new Error('three.js changed its spot falloff; shading.js must be updated');
  }
  THREE_LIGHTS_PARS_GLTF_SPOT = chunk.replace(SPOT_THREE, SPOT_GLTF);
}

// three offsets a surface's shadow lookup along the vertex normal, which on a back face (both
// sides are drawn) points away from the light: the lookup then lands behind the surface's own
// depth and the surface shadows itself. A scene whose winding does not face the light (pandora
// has no normals and mixed winding) goes black. shade.wgsl offsets along the normal turned to the
// side that is seen; here each light's offset is turned to the side that faces that light, which
// is the same wherever the seen side is lit at all.
const SHADOW_OFFSETS = [
  [
    'shadowWorldPosition = worldPosition + vec4( shadowWorldNormal * pointLightShadows[ i ].shadowNormalBias, 0 );',
    // pointShadowMatrix is a translation by minus the light's position.
    'shadowWorldPosition = worldPosition + vec4( bounceTowardLight( shadowWorldNormal, ( pointShadowMatrix[ i ] * worldPosition ).xyz ) * pointLightShadows[ i ].shadowNormalBias, 0 );',
  ],
  [
    'shadowWorldPosition = worldPosition + vec4( shadowWorldNormal * directionalLightShadows[ i ].shadowNormalBias, 0 );',
    // Shadow-map depth grows away from the light: along the normal it must not.
    'shadowWorldPosition = worldPosition + vec4( ( ( directionalShadowMatrix[ i ] * vec4( shadowWorldNormal, 0.0 ) ).z > 0.0 ? - shadowWorldNormal : shadowWorldNormal ) * directionalLightShadows[ i ].shadowNormalBias, 0 );',
  ],
  [
    'shadowWorldPosition.xyz += shadowWorldNormal * spotLightShadows[ i ].shadowNormalBias;',
    // spotLightMatrix is a perspective: compare depths with and without the offset.
    '{ vec3 bounceOffset = shadowWorldNormal * spotLightShadows[ i ].shadowNormalBias; vec4 bounceAt = spotLightMatrix[ i ] * shadowWorldPosition; vec4 bounceOff = spotLightMatrix[ i ] * ( shadowWorldPosition + vec4( bounceOffset, 0.0 ) ); shadowWorldPosition.xyz += bounceOff.z / bounceOff.w > bounceAt.z / bounceAt.w ? - bounceOffset : bounceOffset; }',
  ],
];

let THREE_SHADOWMAP_VERTEX_TOWARD_LIGHT = '#include <shadowmap_vertex>';

// Called once with three's ShaderChunk, so the patch fails loudly if three changes those lines.
export function installShadowOffset(ShaderChunk) {
  let chunk = ShaderChunk.shadowmap_vertex;
  for (const [three, ours] of SHADOW_OFFSETS) {
    if (!chunk.includes(three)) {
      throw new Error("three.js changed its shadow normal offset; shading.js must be updated");
    }
    chunk = chunk.replace(three, ours);
  }
  THREE_SHADOWMAP_VERTEX_TOWARD_LIGHT = chunk;
}

// What the shadow maps are drawn with (for spot and directional lights, and for point lights):
// three's own, plus the native renderer's slope-scaled depth bias (render/src/renderer.rs: constant
// 2, slope 2), which three leaves out. Without it a surface lit at a grazing angle is speckled
// with its own shadow (acne) where the native picture is clean.
export function shadowDepthMaterials() {
  const bias = { polygonOffset: true, polygonOffsetFactor: 2, polygonOffsetUnits: 2 };
  return { depth: new MeshDepthMaterial(bias), distance: new MeshDistanceMaterial(bias) };
}

// The probe-lit sphere's material (probes.js): Lambert of `albedo`, direct light and shadows as
// every surface, and for its indirect light the ambient cube (shade.wgsl's cube_irradiance) read
// with the interpolated normal rather than the volume. `userData.cube` (six Vector3, face order)
// and `userData.indirect` (1 or 0) are its uniforms.
export function objectMaterial(albedo) {
  const cube = { value: Array.from({ length: 6 }, () => new Vector3()) };
  const indirect = { value: 0 };
  const m = new MeshLambertMaterial({ color: new Color(albedo, albedo, albedo) });
  m.userData = { cube, indirect };
  m.onBeforeCompile = (shader) =>
    patchShader(shader, { bounceCube: cube, bounceIndirect: indirect }, OBJECT_FRAGMENT_DECL, OBJECT_FRAGMENT_INDIRECT);
  m.customProgramCacheKey = () => 'bounce-object-v1';
  return m;
}

const OBJECT_FRAGMENT_DECL = /* glsl */ `
uniform vec3 bounceCube[6];
uniform float bounceIndirect;
vec3 bounceCubeIrradiance(vec3 n) {
  vec3 x = n.x < 0.0 ? bounceCube[1] : bounceCube[0];
  vec3 y = n.y < 0.0 ? bounceCube[3] : bounceCube[2];
  vec3 z = n.z < 0.0 ? bounceCube[5] : bounceCube[4];
  return x * n.x * n.x + y * n.y * n.y + z * n.z * n.z;
}
void main() {`;

const OBJECT_FRAGMENT_INDIRECT = /* glsl */ `
if (bounceIndirect > 0.0) {
  irradiance += bounceCubeIrradiance(normalize(inverseTransformDirection(normal, viewMatrix)));
}
#include <lights_fragment_end>`;

// The glTF's material as the native renderer draws it: base colour factor × COLOR_0 × base-colour
// map, emission, no specular, both sides.
export function convertMaterial(source, uniforms) {
  const m = new MeshLambertMaterial({
    name: source.name,
    color: source.color ? source.color.clone() : undefined,
    map: source.map ?? null,
    vertexColors: source.vertexColors === true,
    flatShading: source.flatShading === true,
    side: DoubleSide,
  });
  if (source.emissive) {
    // glTF's emissive is an exitance-like factor that shade.wgsl divides by π like albedo · E.
    m.emissive.copy(source.emissive).multiplyScalar((source.emissiveIntensity ?? 1) / Math.PI);
    m.emissiveMap = source.emissiveMap ?? null;
  }
  m.onBeforeCompile = (shader) => patchShader(shader, uniforms);
  m.customProgramCacheKey = () => 'bounce-volume-v3';
  return m;
}
