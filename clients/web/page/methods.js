// methods.js — the rendering methods the session form offers, with their parameters, defaults and
// help, as the daemon's method registry gives them (GET /v1/methods). The page repeats none of it:
// a method or a parameter the daemon gains appears in the form as it is. The page checks nothing
// itself either: whatever is typed goes to the daemon, which answers invalid values with a 422
// that the page shows.

import { getJson } from './api.js';

// name -> {name, summary, capabilities, refuses, params: [{name, type, default, help, ...}]}
export async function loadMethods() {
  const { methods } = await getJson('/v1/methods');
  return new Map(methods.map((m) => [m.name, m]));
}

// A parameter's default under a session profile ('real_time' or 'converge'): the registry gives
// converge_default where the converge profile changes it.
export function profileDefault(param, profile) {
  return profile === 'converge' && param.converge_default !== undefined ? param.converge_default : param.default;
}

// The form's starting text for a parameter: its default under the profile ('' when the scene
// chooses it).
export function initialText(param, profile = 'real_time') {
  const value = profileDefault(param, profile);
  return value === null || value === undefined ? '' : String(value);
}

// What the form offers for a parameter: its range or choices, and its help.
export function describeParam(param) {
  const range = param.choices
    ? param.choices.join(' | ')
    : param.minimum !== undefined
      ? `${param.exclusive_minimum ? '(' : '['}${param.minimum}, ${param.maximum}${param.exclusive_maximum ? ')' : ']'}`
      : '';
  return range ? `${param.help} — ${range}` : param.help;
}
