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
};
