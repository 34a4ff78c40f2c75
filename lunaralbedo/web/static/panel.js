/* lunaralbedo web map: the run report panel (numbers as in report.json and exposure.csv). */
(function () {
  'use strict';

  function el(tag, attrs, children) {
    const e = document.createElement(tag);
    for (const [k, v] of Object.entries(attrs || {})) e.setAttribute(k, v);
    for (const c of [].concat(children || [])) e.append(c instanceof Node ? c : String(c));
    return e;
  }

  // Full precision (JavaScript's shortest round-trip form, as Python's repr writes report.json).
  function num(v) { return typeof v === 'number' ? String(v) : (v === null || v === undefined ? '' : String(v)); }

  function table(headers, rows, cls) {
    const t = el('table', { class: 'num ' + (cls || '') });
    if (headers) t.append(el('tr', {}, headers.map(h => el('th', {}, h))));
    for (const r of rows) t.append(el('tr', {}, r.map(c => el('td', {}, c instanceof Node ? c : num(c)))));
    return t;
  }

  function section(id, title, body, open) {
    const d = el('details', { id: id }, [el('summary', {}, el('h2', {}, title))]);
    if (open) d.open = true;
    d.append(...[].concat(body));
    return d;
  }

  const SVG = 'http://www.w3.org/2000/svg';
  function svg(tag, attrs, text) {
    const e = document.createElementNS(SVG, tag);
    for (const [k, v] of Object.entries(attrs || {})) e.setAttribute(k, v);
    if (text !== undefined) e.textContent = text;
    return e;
  }

  // A small line plot of ys against xs (numbers), axes annotated with the extreme values.
  function plot(xs, ys, xlabel, ylabel) {
    const w = 360, h = 170, l = 70, r = 8, t = 8, b = 30;
    const ok = xs.map((x, i) => [x, ys[i]]).filter(p => Number.isFinite(p[0]) && Number.isFinite(p[1]));
    const s = svg('svg', { class: 'plot', viewBox: `0 0 ${w} ${h}`, role: 'img', 'aria-label': ylabel + ' vs ' + xlabel });
    if (!ok.length) return s;
    let [x0, x1] = [Math.min(...ok.map(p => p[0])), Math.max(...ok.map(p => p[0]))];
    let [y0, y1] = [Math.min(...ok.map(p => p[1])), Math.max(...ok.map(p => p[1]))];
    if (x1 === x0) x1 = x0 + 1;
    if (y1 === y0) { y0 -= Math.abs(y0) * 1e-3 || 1; y1 += Math.abs(y1) * 1e-3 || 1; }
    const X = x => l + (x - x0) / (x1 - x0) * (w - l - r), Y = y => h - b - (y - y0) / (y1 - y0) * (h - t - b);
    s.append(svg('rect', { x: l, y: t, width: w - l - r, height: h - t - b, fill: 'none', stroke: '#bbb' }));
    s.append(svg('polyline', { points: ok.map(p => `${X(p[0])},${Y(p[1])}`).join(' '), fill: 'none', stroke: '#1565c0', 'stroke-width': 1.5 }));
    for (const p of ok) s.append(svg('circle', { cx: X(p[0]), cy: Y(p[1]), r: 2, fill: '#1565c0' }));
    s.append(svg('text', { x: l - 3, y: t + 9, 'text-anchor': 'end' }, y1.toPrecision(6)));
    s.append(svg('text', { x: l - 3, y: h - b, 'text-anchor': 'end' }, y0.toPrecision(6)));
    s.append(svg('text', { x: l, y: h - b + 12 }, x0));
    s.append(svg('text', { x: w - r, y: h - b + 12, 'text-anchor': 'end' }, x1));
    s.append(svg('text', { x: (l + w) / 2, y: h - 4, 'text-anchor': 'middle' }, xlabel));
    s.append(svg('text', { x: 10, y: (t + h - b) / 2, transform: `rotate(-90 10 ${(t + h - b) / 2})`, 'text-anchor': 'middle' }, ylabel));
    return s;
  }

  function keyValues(obj) {
    return table(null, Object.entries(obj).map(([k, v]) => [k, Array.isArray(v) ? v.map(num).join(', ') : (v && typeof v === 'object' ? JSON.stringify(v) : v)]), 'kv');
  }

  // Whatever a result carries beyond the default solve (e.g. an estimated camera response):
  // scalars as a table, the first two equal-length numeric arrays as a curve.
  function extra(id, title, obj) {
    if (!obj || typeof obj !== 'object') return null;
    const arrays = Object.entries(obj).filter(([, v]) => Array.isArray(v) && v.length && v.every(x => typeof x === 'number'));
    const body = [];
    const pair = arrays.find(([, a], i) => arrays.some(([, b], j) => j > i && b.length === a.length));
    if (pair) {
      const other = arrays.find(([k, b]) => k !== pair[0] && b.length === pair[1].length);
      body.push(plot(pair[1], other[1], pair[0], other[0]));
      body.push(table([pair[0], other[0]], pair[1].map((x, i) => [x, other[1][i]])));
    }
    const scalars = Object.fromEntries(Object.entries(obj).filter(([, v]) => !Array.isArray(v) || !v.every(x => typeof x === 'number')));
    if (Object.keys(scalars).length) body.push(keyValues(scalars));
    return section(id, title, body, false);
  }

  // FLOAT_HAZE 1: each image's additive haze (haze.csv as written; report.json's when the file is absent),
  // beside the exposures, with its standard error and whether it separates from the exposure.
  function haze(report, rows) {
    const values = rows.length ? rows.map(r => [r.key, r.haze]) : Object.entries(report.haze || {});
    if (!values.length) return null;
    const bad = new Set(report.haze_inseparable || []), sigma = report.haze_sigma || {};
    const se = v => typeof v === 'number' ? v.toPrecision(3) : '';
    return section('haze', `Haze (${values.length} images, DRG units)`,
      [plot(values.map((_, i) => i + 1), values.map(r => r[1]), 'image (exposure.csv order)', 'haze'),
       table(['key', 'haze', '\u00b1', 'separable'], values.map(([k, h]) => [k, h, se(sigma[k]), bad.has(k) ? 'NO' : 'yes'])),
       el('p', { class: 'note' }, (rows.length ? 'haze.csv' : 'report.json haze') + '; \u00b1: standard error (report.json haze_sigma); separable NO: too little ' +
         'contrast in the image to tell its haze from its exposure (the solve warned).')], true);
  }

  // REGISTER_IMAGES 1: the ground shift added to each image's stated position (image_offsets.csv as written,
  // metres, with standard errors), and in the image's pixels (report.json registration.offsets_px).
  function offsets(report, rows) {
    if (!rows.length) return null;
    const px = (report.registration || {}).offsets_px || {};
    const body = [table(['key', 'east', 'north', '\u00b1 east', '\u00b1 north'],
      rows.map(r => [r.key, r.east_m, r.north_m, r.east_se_m, r.north_se_m]), 'offsets-m'),
      el('p', { class: 'note' }, 'image_offsets.csv (east_m, north_m, east_se_m, north_se_m): the shift added to each ' +
        "image's stated ground position to put it on the DEM, and its standard errors; the footprints are drawn moved by it.")];
    if (Object.keys(px).length) {
      body.push(table(['key', 'east, image px', 'north, image px'], rows.map(r => [r.key, ...(px[r.key] || ['', ''])]), 'offsets-px'));
    }
    return section('offsets', `Image offsets (${rows.length} images, metres on the ground)`, body, true);
  }

  // REFINE_DEM 1: the height change's RMS and the rounds; the map shows the hillshade before and after.
  function refineDem(d) {
    if (!d) return null;
    const scalars = Object.fromEntries(Object.entries(d).filter(([k]) => k !== 'rounds'));
    const rounds = d.rounds || [];
    return section('refine_dem', 'Refined DEM (REFINE_DEM)', [keyValues(scalars),
      table(['round', 'change RMS m', 'L-BFGS iterations', 'CPU s'],
        rounds.map(r => [r.round, r.change_rms_m, (r.lbfgs_iterations || []).join(' '), r.cpu_s]))], false);
  }

  function render(root, report, exposures, meta, tables) {
    tables = tables || {};
    const q = report.cost_q || [];
    const params = report.parameters || {};
    const names = Object.keys(params);
    const parts = [];
    parts.push(section('summary', 'Run', keyValues({
      method: report.method, executor: report.executor, iterations: report.iterations, converged: report.converged,
      images_used: report.images_used, images_skipped: Object.keys(report.images_skipped || {}).length ? report.images_skipped : 'none',
      resumed: report.resumed === null || report.resumed === undefined ? 'no' : report.resumed,
    }), true));
    if (exposures.length) {
      const rows = exposures.map(r => [r.key, r.exposure, r.initial_exposure, (100 * (r.exposure / r.initial_exposure - 1)).toFixed(3)]);
      parts.push(section('exposures', `Exposures (${exposures.length} images)`,
        [plot(exposures.map((_, i) => i + 1), exposures.map(r => r.exposure), 'image (exposure.csv order)', 'exposure'),
         table(['key', 'exposure', 'initial', 'change %'], rows)], true));
    }
    for (const s of [haze(report, tables.haze || []), offsets(report, tables.image_offsets || [])]) if (s) parts.push(s);
    if (report.outliers) {  // the robust weights: per image the observations rejected or down-weighted
      const im = report.outliers.images;
      parts.push(section('outliers', `Outliers (${(100 * report.outliers.rejected_fraction).toFixed(3)} % rejected)`,
        table(['key', 'observations', 'rejected %', 'down-weighted %'], Object.keys(im).map(k =>
          [k, im[k].observations, (100 * im[k].rejected_fraction).toFixed(3), (100 * im[k].downweighted_fraction).toFixed(3)])), false));
    }
    if (q.length) {
      parts.push(section('cost', 'Q per iteration', [plot(q.map((_, i) => i + 1), q, 'iteration', 'Q'),
        table(['iteration', 'Q'], q.map((v, i) => [i + 1, v]))], true));
    }
    if (names.length) {
      // the photometric model's fitted parameters per iteration (iteration 0 is the initial value)
      const rows = params[names[0]].map((_, i) => [i, ...names.map(n => params[n][i])]);
      parts.push(section('parameters', `Model parameters (${report.photometric_model})`, table(['iteration', ...names], rows), false));
    }
    const dem = refineDem(report.refine_dem);
    if (dem) parts.push(dem);
    for (const [key, title] of [['response', 'Camera response'], ['residuals', 'Residuals']]) {
      const s = extra(key, title, report[key]);
      if (s) parts.push(s);
    }
    if (report.timings_s) {
      const t = report.timings_s, total = Object.values(t).reduce((a, b) => a + b, 0);
      parts.push(section('timings', 'Timings (s)', table(['step', 's'], [...Object.entries(t), ['total', Number(total.toFixed(3))]]), false));
    }
    if (report.tiles) {
      parts.push(section('tiles', `Tiles (${report.tiles.length})`, table(['tile', 'valid px', 'images', 'without usable px'],
        report.tiles.map(t => [t.tile, t.valid_pixels, (t.images || []).length, (t.images_without_usable_pixels || []).join(' ')])), false));
    }
    if (report.settings) parts.push(section('settings', 'Settings', keyValues(report.settings), false));
    parts.push(section('map-facts', 'Map', keyValues({
      extent: meta.bounds.join(', '), native_size: meta.native_size.join(' x '), pyramid_levels: meta.levels,
      tile_size: meta.tile_size, layers: meta.layers.map(l => l.stretch ? `${l.id} ${num(l.stretch.lo)}..${num(l.stretch.hi)}` : l.id).join('; '),
      footprints: meta.footprints, generator: meta.generator,
    }), false));
    root.replaceChildren(...parts);
  }

  window.LunarPanel = { render: render, table: table, el: el, num: num };
})();
