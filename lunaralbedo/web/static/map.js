/* lunaralbedo web map: Leaflet on the Moon's plate carree (lon/lat degrees, 1737.4 km sphere). */
(function () {
  'use strict';
  const META = window.LUNARALBEDO_META;
  const REPORT = window.LUNARALBEDO_REPORT || {};
  const EXPOSURES = window.LUNARALBEDO_EXPOSURES || [];
  const TABLES = window.LUNARALBEDO_TABLES || {};
  const LABELS = META.value_labels || { albedo: 'albedo', error: 'error' };
  const EXTRA = (META.values || []).filter(n => n !== 'albedo' && n !== 'error');  // outliers, dem_change
  const FOOT = window.LUNARALBEDO_FOOTPRINTS || { type: 'FeatureCollection', features: [] };
  const P = window.LunarPanel;
  const [W, S, E, N] = META.bounds;
  const [RW, RH] = META.root_size;
  const [FW, FH] = META.finest_size;
  const TS = META.tile_size;
  const FINEST = META.levels - 1;

  document.title = `${META.name} - lunaralbedo`;
  document.getElementById('title').textContent = META.name;
  document.getElementById('subtitle').textContent =
    `lon ${W}..${E}, lat ${S}..${N}; ${META.native_size.join(' x ')} px; ${EXPOSURES.length || REPORT.images_used || 0} images`;

  // Zoom z shows pyramid level z: RW * 2^z pixels across the data's longitudes.
  const ax = RW / (E - W), ay = RH / (N - S);
  const crs = L.extend({}, L.CRS.Earth, {
    code: 'MOON-PLATE-CARREE',
    projection: L.Projection.LonLat,
    transformation: new L.Transformation(ax, -W * ax, -ay, N * ay),
    scale: z => Math.pow(2, z),
    zoom: s => Math.log(s) / Math.LN2,
    R: META.radius_m, // CRS.Earth's haversine distance on the Moon's sphere: the scale bar is in lunar metres
    wrapLng: undefined,
    infinite: true,
  });
  const dataBounds = L.latLngBounds([[S, W], [N, E]]);
  const map = L.map('map', { crs: crs, minZoom: -3, maxZoom: FINEST + 4, zoomSnap: 0.25, attributionControl: false });

  const present = new Set();
  for (const [z, list] of Object.entries(META.tiles)) for (const [x, y] of list) present.add(`${z}/${x}/${y}`);
  const BLANK = 'data:image/gif;base64,R0lGODlhAQABAIAAAAAAACH5BAEAAAAALAAAAAABAAEAAAIBRAA7';
  const PyramidLayer = L.TileLayer.extend({
    getTileUrl: function (c) {
      const key = `${c.z}/${c.x}/${c.y}`;
      return present.has(key) ? `tiles/${this.options.layerId}/${key}.png` : BLANK;
    },
  });
  const bases = {}, layerById = {};
  for (const l of META.layers) {
    const layer = new PyramidLayer('', { layerId: l.id, tileSize: TS, minNativeZoom: 0, maxNativeZoom: FINEST, bounds: dataBounds, noWrap: true });
    bases[l.name] = layerById[l.id] = layer;
  }

  // Graticule: meridians and parallels at a round step for the visible span, labelled in degrees.
  const STEPS = [90, 45, 30, 20, 10, 5, 2, 1, 0.5, 0.2, 0.1, 0.05, 0.02, 0.01, 0.005, 0.002, 0.001];
  const deg = (v, pos, neg) => `${Math.abs(+v.toFixed(6))}\u00b0${v >= 0 ? pos : neg}`;
  const Graticule = L.LayerGroup.extend({
    onAdd: function (m) { L.LayerGroup.prototype.onAdd.call(this, m); m.on('moveend', this.redraw, this); this.redraw(); },
    onRemove: function (m) { m.off('moveend', this.redraw, this); L.LayerGroup.prototype.onRemove.call(this, m); },
    redraw: function () {
      this.clearLayers();
      const b = this._map.getBounds(), s = Math.max(b.getSouth(), -90), n = Math.min(b.getNorth(), 90);
      const span = Math.max(b.getEast() - b.getWest(), n - s);
      const step = STEPS.find(v => span / v >= 3) || STEPS[STEPS.length - 1];
      const line = { color: '#4fc3f7', weight: 1, opacity: 0.55, interactive: false };
      const label = (ll, text, anchor) => this.addLayer(L.marker(ll, { interactive: false, keyboard: false,
        icon: L.divIcon({ className: 'grat-label', html: text, iconSize: null, iconAnchor: anchor }) }));
      for (let lon = Math.ceil(b.getWest() / step) * step; lon <= b.getEast(); lon += step) {
        this.addLayer(L.polyline([[s, lon], [n, lon]], line));
        label([n, lon], deg(((lon + 540) % 360) - 180, 'E', 'W'), [-3, -2]);
      }
      for (let lat = Math.ceil(s / step) * step; lat <= n; lat += step) {
        this.addLayer(L.polyline([[lat, b.getWest()], [lat, b.getEast()]], line));
        label([lat, b.getWest()], deg(lat, 'N', 'S'), [-3, 14]);
      }
    },
  });
  const graticule = new Graticule();

  const fmt = (v, p) => (v === null || v === undefined || Number.isNaN(v)) ? 'no data' : v.toPrecision(p);
  const footprints = L.geoJSON(FOOT, {
    style: { color: '#ffb300', weight: 1.5, opacity: 0.9, fillOpacity: 0.03 },
    onEachFeature: (f, layer) => {
      const p = f.properties;
      layer.bindTooltip(`<b>${p.key}</b><br>exposure ${p.exposure === undefined ? 'n/a' : fmt(p.exposure, 7)}` +
        (p.initial_exposure === undefined ? '' : `<br>initial ${fmt(p.initial_exposure, 7)}`) +
        (p.east_m === undefined ? '' : `<br>moved ${fmt(p.east_m, 6)} m east, ${fmt(p.north_m, 6)} m north`), { sticky: true });
      layer.on('mouseover', () => layer.setStyle({ weight: 3, fillOpacity: 0.12 }));
      layer.on('mouseout', () => footprints.resetStyle(layer));
    },
  });
  const overlays = { 'Image footprints': footprints, 'Lon/lat graticule': graticule };

  layerById.albedo.addTo(map);
  footprints.addTo(map);
  graticule.addTo(map);
  L.control.layers(bases, overlays, { collapsed: false }).addTo(map);
  L.control.scale({ metric: true, imperial: false, maxWidth: 200 }).addTo(map);

  // Legend of the shown layer's stretch.
  const legend = L.control({ position: 'bottomright' });
  legend.onAdd = () => L.DomUtil.create('div', 'legend');
  legend.addTo(map);
  function showLegend(id) {
    const l = META.layers.find(x => x.id === id);
    const ramp = l.ramp ? `linear-gradient(to right, ${l.ramp.join(', ')})` : 'linear-gradient(to right, #000, #fff)';
    const unit = l.unit ? ` ${l.unit}` : '';
    const ends = l.stretch ? [fmt(l.stretch.lo, 4) + unit, fmt(l.stretch.hi, 4) + unit] : ['shadow', 'lit (sun az 315\u00b0, alt 45\u00b0)'];
    legend.getContainer().innerHTML = `<b>${l.name}</b><div class="ramp" style="background:${ramp}"></div>` +
      `<div class="ends"><span>${ends[0]}</span><span>${ends[1]}</span></div>`;
  }
  showLegend('albedo');
  map.on('baselayerchange', e => showLegend(e.layer.options.layerId));

  const cursor = L.control({ position: 'bottomleft' });
  cursor.onAdd = () => L.DomUtil.create('div', 'cursor-pos');
  cursor.addTo(map);
  map.on('mousemove', e => { cursor.getContainer().textContent = `lon ${e.latlng.lng.toFixed(5)}  lat ${e.latlng.lat.toFixed(5)}`; });

  // Values on click: the finest-level tile's albedo, error (and outliers, dem_change), from data/values/<col>/<row>.js.
  const cache = new Map(), waiting = new Map();
  function decode(b64) {
    const bin = atob(b64), bytes = new Uint8Array(bin.length);
    for (let i = 0; i < bin.length; i++) bytes[i] = bin.charCodeAt(i);
    return new Float32Array(bytes.buffer);
  }
  window.LUNARALBEDO_VALUES = function (col, row, payload) {
    const key = `${col}/${row}`, tile = { width: payload.width, height: payload.height };
    for (const name of META.values) if (payload[name]) tile[name] = decode(payload[name]);
    cache.set(key, tile);
    for (const resolve of waiting.get(key) || []) resolve(tile);
    waiting.delete(key);
  };
  function loadValues(col, row) {
    const key = `${col}/${row}`;
    if (cache.has(key)) return Promise.resolve(cache.get(key));
    if (!present.has(`${FINEST}/${key}`)) return Promise.resolve(null);
    return new Promise(resolve => {
      if (!waiting.has(key)) {
        waiting.set(key, []);
        const s = document.createElement('script');
        s.src = `data/values/${key}.js`;
        s.onerror = () => { for (const r of waiting.get(key) || []) r(null); waiting.delete(key); };
        document.head.appendChild(s);
      }
      waiting.get(key).push(resolve);
    });
  }
  function pixelAt(ll) {
    const x = Math.floor((ll.lng - W) / (E - W) * FW), y = Math.floor((N - ll.lat) / (N - S) * FH);
    if (x < 0 || y < 0 || x >= FW || y >= FH) return null;
    return { x: x, y: y, col: Math.floor(x / TS), row: Math.floor(y / TS), i: x % TS, j: y % TS };
  }
  function inRing(lon, lat, ring) {
    let inside = false;
    for (let i = 0, j = ring.length - 1; i < ring.length; j = i++) {
      const [xi, yi] = ring[i], [xj, yj] = ring[j];
      if ((yi > lat) !== (yj > lat) && lon < (xj - xi) * (lat - yi) / (yj - yi) + xi) inside = !inside;
    }
    return inside;
  }
  function imagesSeen(ll) {
    return FOOT.features.filter(f => {
      const polys = f.geometry.type === 'Polygon' ? [f.geometry.coordinates] : f.geometry.coordinates;
      return polys.some(p => inRing(ll.lng, ll.lat, p[0]) && !p.slice(1).some(h => inRing(ll.lng, ll.lat, h)));
    }).map(f => f.properties.key);
  }
  const popup = L.popup({ maxWidth: 320 });
  async function showValues(ll) {
    const px = pixelAt(ll), tile = px && await loadValues(px.col, px.row);
    const at = tile ? px.j * tile.width + px.i : -1;
    const value = name => (tile && tile[name]) ? tile[name][at] : null;
    const albedo = value('albedo'), error = value('error'), seen = imagesSeen(ll);
    const extra = Object.fromEntries(EXTRA.map(n => [n, value(n)]));
    const rows = [['lon', `${ll.lng.toFixed(6)}\u00b0`], ['lat', `${ll.lat.toFixed(6)}\u00b0`],
      ['albedo', fmt(albedo, 7)], ['error', fmt(error, 4)], ...EXTRA.map(n => [LABELS[n], fmt(extra[n], 7)]),
      ['pixel', px ? `${px.x}, ${px.y} (level ${FINEST})` : 'outside'],
      [`images seen (${seen.length})`, seen.join(' ') || 'none']];
    const box = document.getElementById('readout');
    box.replaceChildren(P.table(null, rows, 'kv'));
    const data = { lon: ll.lng, lat: ll.lat, albedo: albedo, error: error, ...extra };
    for (const [k, v] of Object.entries(data)) box.dataset[k] = v === null ? '' : v;
    box.dataset.images = seen.join(' ');
    popup.setLatLng(ll).setContent(P.table(null, rows, 'kv').outerHTML).openOn(map);
    return { albedo: albedo, error: error, ...extra, images: seen };
  }
  map.on('click', e => { showValues(e.latlng); });

  layerById.albedo.on('load', () => { document.body.dataset.mapReady = '1'; });
  map.fitBounds(dataBounds);
  P.render(document.getElementById('report'), REPORT, EXPOSURES, META, TABLES);
  window.lunaralbedo = { map: map, layers: layerById, overlays: { footprints: footprints, graticule: graticule }, showValues: showValues, pixelAt: pixelAt };
})();
