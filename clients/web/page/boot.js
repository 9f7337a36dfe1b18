// boot.js — a classic script, so it runs even when the page's modules do not: if app.js has
// not started by the time the page has loaded (a module failed to load or parse, or the
// browser has no ES modules), say so instead of leaving controls that do nothing.
window.addEventListener('load', () => {
  if (document.body.dataset.started) return;
  const box = document.createElement('div');
  box.className = 'problem';
  box.dataset.status = '0';
  box.textContent =
    'The page did not start: its scripts failed to load or run (the browser console says which). ' +
    'The daemon itself may be fine: GET /healthz.';
  document.getElementById('messages').prepend(box);
});
