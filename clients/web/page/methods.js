// methods.js — the rendering methods the session form offers and their parameters, as
// protocol/API.md lists them for POST /v1/scenes/{scene}/sessions. The page checks nothing
// itself: whatever is typed goes to the daemon, which answers invalid values with a 422 that the
// page shows. Add a method here when the daemon gains one.

export const METHODS = {
  pt: {
    label: 'pt: path tracing (the reference integrator)',
    params: [
      { name: 'spp', kind: 'number', value: 1, help: 'samples per pixel per frame' },
      { name: 'max_depth', kind: 'number', value: 64, help: 'longest path, in bounces' },
      { name: 'rr_depth', kind: 'number', value: 3, help: 'bounce where Russian roulette starts' },
      { name: 'nee', kind: 'boolean', value: true, help: 'next-event estimation' },
    ],
  },
  sms: {
    label: 'sms: path tracing with specular manifold sampling of caustics',
    params: [
      { name: 'spp', kind: 'number', value: 1, help: 'samples per pixel per frame' },
      { name: 'bernoulli_cap', kind: 'number', value: 128, help: 'Bernoulli trials per solution (0: uncapped)' },
      { name: 'max_iterations', kind: 'number', value: 20, help: 'Newton steps per manifold walk' },
      { name: 'caustics_only', kind: 'boolean', value: false, help: 'only the caustics SMS owns' },
      { name: 'max_depth', kind: 'number', value: 64, help: 'longest path, in bounces' },
    ],
  },
  sms_ssp: {
    label: 'sms_ssp: SMS with sample-space partitioning and a per-frame prior',
    params: [
      { name: 'spp', kind: 'number', value: 1, help: 'samples per pixel per frame' },
      { name: 'tiles', kind: 'number', value: 16, help: 'N x N tiles of the seed space' },
      { name: 'prior', kind: 'boolean', value: true, help: 'per-frame prior from 16x16 pixel blocks' },
      { name: 'prior_samples', kind: 'number', value: 128, help: 'prior walks per block' },
      { name: 'prior_frames', kind: 'number', value: 4, help: 'frames of walks a still view\'s prior unites' },
      { name: 'alpha', kind: 'number', value: 0.8, help: 'mixing weight of the prior' },
      { name: 'bernoulli_cap', kind: 'number', value: 128, help: 'Bernoulli trials per solution (0: uncapped)' },
      { name: 'caustics_only', kind: 'boolean', value: false, help: 'only the caustics SMS owns' },
    ],
  },
  restir_pt: {
    label: 'restir_pt: ReSTIR path tracing (reuse across pixels and frames)',
    params: [
      { name: 'spatial_neighbors', kind: 'number', value: 3, help: 'neighbours per spatial round (0: none)' },
      { name: 'spatial_radius', kind: 'number', value: 20, help: 'spatial radius, pixels' },
      { name: 'paired_spatial', kind: 'boolean', value: true, help: 'paired neighbours (half the shifts)' },
      { name: 'temporal', kind: 'boolean', value: true, help: 'temporal reuse' },
      { name: 'temporal_cap', kind: 'number', value: 20, help: 'previous confidence cap, x current' },
      { name: 'nee_candidates', kind: 'number', value: '', help: 'RIS candidates of light sampling (empty: 4 with several lights, 1 with one)' },
      { name: 'footprint', kind: 'boolean', value: true, help: 'dual ray-footprint reconnection threshold' },
      { name: 'pdf_connect', kind: 'boolean', value: true, help: 'PDF-based connectability' },
      { name: 'unify_di', kind: 'boolean', value: true, help: 'direct light in the reservoir' },
      { name: 'max_depth', kind: 'number', value: 64, help: 'longest path, in bounces' },
    ],
  },
  bdpt: {
    label: 'bdpt: bidirectional path tracing (light vertex cache, recursive MIS)',
    params: [
      { name: 'light_paths', kind: 'number', value: 0, help: 'light subpaths per frame (0: the pixel count)' },
      { name: 'heuristic', kind: 'text', value: 'power', help: 'MIS heuristic: power or balance' },
      { name: 'lvc_capacity', kind: 'number', value: 8, help: 'cached light vertices per light subpath' },
      { name: 'max_depth', kind: 'number', value: 64, help: 'longest path, in bounces' },
    ],
  },
  restir_bdpt: {
    label: 'restir_bdpt: ReSTIR BDPT, lightweight (s=0, s=1, t=1; caustics reused over frames)',
    params: [
      { name: 'light_paths', kind: 'number', value: 0, help: 'light subpaths per frame (0: the pixel count)' },
      { name: 'heuristic', kind: 'text', value: 'power', help: 'MIS heuristic: power or balance' },
      { name: 'caustic_temporal', kind: 'boolean', value: true, help: 'temporal reuse of caustic reservoirs' },
      { name: 'reuse', kind: 'boolean', value: false, help: 'temporal and spatial reuse of the rest (hybrid shifts)' },
      { name: 'spatial_neighbors', kind: 'number', value: 2, help: 'with reuse: spatial neighbours' },
      { name: 'temporal_cap', kind: 'number', value: 20, help: 'caustic confidence cap' },
      { name: 'moving_cap', kind: 'number', value: 1, help: 'caustic confidence cap while shapes or lights move' },
      { name: 'lt_capacity', kind: 'number', value: 8, help: 'light-traced samples kept per light subpath' },
      { name: 'max_depth', kind: 'number', value: 64, help: 'longest path, in bounces' },
    ],
  },
  restir_sss: {
    label: 'restir_sss: ReSTIR subsurface scattering (translucent materials)',
    params: [
      { name: 'shift', kind: 'text', value: 'hybrid', help: 'reconnection, delayed, hybrid or sequential' },
      { name: 'candidates', kind: 'number', value: 1, help: 'BSSRDF probes per pixel and frame' },
      { name: 'target', kind: 'text', value: 'luminance', help: 'luminance, or per_channel (a reservoir per colour channel: 3x the reuse, no colour noise)' },
      { name: 'spatial_neighbors', kind: 'number', value: 4, help: 'spatial neighbours (0: none)' },
      { name: 'spatial_radius', kind: 'number', value: 0, help: 'spatial radius, pixels (0: from 2 max d)' },
      { name: 'temporal', kind: 'boolean', value: true, help: 'temporal reuse' },
      { name: 'temporal_cap', kind: 'number', value: 20, help: 'previous confidence cap, x current' },
    ],
  },
  restir_sms: {
    label: 'restir_sms: ReSTIR over specular manifold samples (caustics)',
    params: [
      { name: 'sampler', kind: 'text', value: 'ssp', help: 'candidates: ssp (partitioning + prior) or sms' },
      { name: 'shift_iterations', kind: 'number', value: 5, help: 'Newton steps per manifold shift walk' },
      { name: 'spatial_neighbors', kind: 'number', value: 1, help: 'spatial neighbours (0: none)' },
      { name: 'spatial_radius', kind: 'number', value: 30, help: 'spatial radius, pixels' },
      { name: 'paired_spatial', kind: 'boolean', value: true, help: 'paired neighbours (half the shifts)' },
      { name: 'temporal', kind: 'boolean', value: true, help: 'temporal reuse' },
      { name: 'temporal_cap', kind: 'number', value: 20, help: 'previous confidence cap, x current' },
      { name: 'bernoulli_cap', kind: 'number', value: 128, help: 'Bernoulli trials per solution (0: uncapped)' },
      { name: 'jitter_walk', kind: 'number', value: 0.1, help: 'primary ray moves at most this per frame, pixels (0: fresh)' },
      { name: 'light_reservoirs', kind: 'number', value: 0, help: 'reservoirs per pixel, by light (0: one per emitter)' },
      { name: 'caustics_only', kind: 'boolean', value: false, help: 'only the caustics SMS owns' },
    ],
  },
};
