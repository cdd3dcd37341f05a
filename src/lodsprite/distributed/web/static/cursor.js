// The point under the cursor, in the dataset's own coordinates: the ray through a canvas
// pixel from the shown viewpoint meets the coarse level (ErrorMetric.alongTrack, the
// triangles the page draws), and that world point (metres from the terrain's centre,
// heights exaggerated) is taken back to the dataset's CRS by the scene's georeference
// (lodsprite.terrain.rasters.georef: easting = x / metres-per-unit east + the bounds'
// centre, the same for northing; height = z / exaggeration), as lodsprite.paths.core.
// dataset_to_world takes it forward.

import { add, scale, unit } from './camera.js';

// The world direction of the ray through pixel (px, py) (top-left origin, CSS pixels of
// a w x h canvas) from viewpoint vp ({x, y, z, o}: the camera looks along -z), vertical
// field of view fovDeg.
export function pixelRay(vp, px, py, w, h, fovDeg) {
  const t = Math.tan((fovDeg * Math.PI) / 360);
  const u = ((2 * (px + 0.5)) / w - 1) * t * (w / h);
  const v = (1 - (2 * (py + 0.5)) / h) * t;
  return unit(add(add(scale(vp.x, u), scale(vp.y, v)), scale(vp.z, -1)));
}

// World point (x, y, z) -> {e, n, h}: the dataset's easting and northing (its CRS units)
// and height (metres above its datum), by `georef` ({bounds: [w, s, e, n],
// metres_per_unit: [fx, fy]}) and the scene's vertical `exaggeration`.
export function worldToDataset(p, georef, exaggeration = 1) {
  const [w, s, e, n] = georef.bounds, [fx, fy] = georef.metres_per_unit;
  return { e: p[0] / fx + 0.5 * (w + e), n: p[1] / fy + 0.5 * (s + n), h: p[2] / exaggeration };
}

// What the cursor at (px, py) points at: {world: [x, y, z], e, n, h, crs} (e, n, h null
// without a georeference: then h is the world height over the exaggeration), or null
// where its ray meets no terrain.
export function cursorPoint(metric, vp, px, py, w, h, fovDeg, georef, exaggeration = 1) {
  const d = pixelRay(vp, px, py, w, h, fovDeg);
  const t = metric.alongTrack(vp.o, d, true);
  if (!Number.isFinite(t)) return null;
  const world = add(vp.o, scale(d, t));
  if (!georef) return { world, e: null, n: null, h: world[2] / exaggeration, crs: null };
  return { world, ...worldToDataset(world, georef, exaggeration), crs: georef.crs };
}
