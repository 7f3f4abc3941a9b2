/* report.html's 3D viewer: reports/viewer.py inlines this script after the three.js bundle (the
 * global THREE) and writes its data into <script id="viewer-data">: per shape, one view per mesh
 * (the GT, then each method) with its Draco-compressed GLB in base64. Every view has its own WebGL
 * canvas, camera and OrbitControls; moving one camera moves all the others (follow). The toggles
 * show the error colours baked into each prediction (COLOR_0), the sharp-edge points (the GT's in
 * every view, the prediction's over them) and a wireframe. window.salsbenchViewer exposes the state
 * for tests and the console. Nothing is fetched: the decoder comes from the page through blob URLs. */
(function () {
  'use strict';
  const T = window.THREE;
  const dataElement = document.getElementById('viewer-data');
  const grid = document.getElementById('viewer-grid');
  if (!T || !dataElement || !grid) return;
  const data = JSON.parse(dataElement.textContent);
  const picker = document.getElementById('viewer-shape');
  const toggles = {
    error: document.getElementById('viewer-error'),
    edges: document.getElementById('viewer-edges'),
    wireframe: document.getElementById('viewer-wire'),
  };
  // Colours are used as written (sRGB values lit in display space, as the thumbnails are).
  T.ColorManagement.enabled = false;

  function bytesOf(base64) {
    const text = atob(base64);
    const out = new Uint8Array(text.length);
    for (let i = 0; i < text.length; i++) out[i] = text.charCodeAt(i);
    return out;
  }

  const draco = new T.DRACOLoader();
  draco.setDecoderPath({
    js: URL.createObjectURL(new Blob([document.getElementById('viewer-draco').textContent], { type: 'text/javascript' })),
    wasm: URL.createObjectURL(new Blob([bytesOf(data.dracoWasm)], { type: 'application/wasm' })),
  });
  const loader = new T.GLTFLoader();
  loader.setDRACOLoader(draco);

  const views = [];
  const state = { shape: -1, error: false, edges: false, wireframe: false, loaded: false };
  let following = false;
  let frameRequested = false;

  function makeView(index) {
    const cell = document.createElement('figure');
    cell.className = 'vcell';
    const title = document.createElement('figcaption');
    title.className = 'name';
    const canvas = document.createElement('canvas');
    const message = document.createElement('div');
    message.className = 'ph missing';
    const caption = document.createElement('figcaption');
    caption.className = 'm';
    cell.append(title, canvas, message, caption);
    grid.append(cell);
    const renderer = new T.WebGLRenderer({ canvas, antialias: true, preserveDrawingBuffer: true });
    renderer.outputColorSpace = T.LinearSRGBColorSpace;
    renderer.setPixelRatio(window.devicePixelRatio || 1);
    renderer.setClearColor(0xffffff, 1);
    const scene = new T.Scene();
    const camera = new T.PerspectiveCamera(30, 1, 0.01, 100);
    const up = data.shapes.length && data.shapes[0].camera ? data.shapes[0].camera.up : [0, 1, 0];
    camera.up.set(up[0], up[1], up[2]);
    scene.add(camera);
    // Lights in camera coordinates, weighted as the thumbnails' (reports/render.py).
    scene.add(new T.AmbientLight(0xffffff, 0.2 * Math.PI));
    const aim = new T.Object3D();
    camera.add(aim);
    for (const [x, y, z, weight] of [[-0.45, 0.8, 0.55, 0.6], [0.75, 0.05, 0.65, 0.28]]) {
      const light = new T.DirectionalLight(0xffffff, weight * Math.PI);
      light.position.set(x, y, z);
      light.target = aim;
      camera.add(light);
    }
    const controls = new T.OrbitControls(camera, canvas);
    controls.addEventListener('change', () => follow(index));
    const content = new T.Group();
    scene.add(content);
    return { cell, title, canvas, message, caption, renderer, scene, camera, controls, content, parts: {}, status: 'empty' };
  }

  function follow(source) {
    if (following) return;
    following = true;
    const from = views[source];
    for (const view of views) {
      if (view === from) continue;
      view.camera.position.copy(from.camera.position);
      view.camera.quaternion.copy(from.camera.quaternion);
      view.camera.zoom = from.camera.zoom;
      view.camera.near = from.camera.near;
      view.camera.far = from.camera.far;
      view.camera.updateProjectionMatrix();
      view.controls.target.copy(from.controls.target);
    }
    following = false;
    requestRender();
  }

  function resize(view) {
    const size = Math.max(view.canvas.clientWidth || 0, 64);
    view.renderer.setSize(size, size, false);
    view.camera.aspect = 1;
    view.camera.updateProjectionMatrix();
  }

  function renderNow() {
    frameRequested = false;
    for (const view of views) if (view.status === 'ok') view.renderer.render(view.scene, view.camera);
  }

  function requestRender() {
    if (frameRequested) return;
    frameRequested = true;
    requestAnimationFrame(renderNow);
  }

  function parse(base64) {
    return new Promise((resolve, reject) => loader.parse(bytesOf(base64).buffer, '', resolve, reject));
  }

  function clear(view) {
    for (const object of [...view.content.children]) {
      view.content.remove(object);
      object.material.dispose();
      if (object.userData.ownsGeometry) object.geometry.dispose();
    }
    view.parts = {};
  }

  function part(gltf, name) {
    const object = gltf.scene.getObjectByName(name);
    if (!object) return null;
    if (object.material) object.material.dispose();
    return object.geometry;
  }

  function surfaceMaterial(isGT) {
    return new T.MeshPhongMaterial({
      color: isGT ? data.gtColor : data.baseColor, flatShading: true, side: T.DoubleSide,
      specular: 0x1a1a1a, shininess: 24, polygonOffset: true, polygonOffsetFactor: 1, polygonOffsetUnits: 1,
    });
  }

  function pointsOf(geometry, owns) {
    const points = new T.Points(geometry, new T.PointsMaterial({ size: 3, sizeAttenuation: false, vertexColors: true }));
    points.userData.ownsGeometry = owns;
    return points;
  }

  function fill(view, spec, gltf, gtEdges, isGT) {
    clear(view);
    view.title.innerHTML = '';
    if (!isGT) {
      const dot = document.createElement('i');
      dot.className = 'dot';
      dot.style.background = data.dots[spec.name] || '#888';
      view.title.append(dot);
    }
    view.title.append(spec.name);
    const count = (n) => n.toLocaleString('en');
    const drawn = spec.faces < spec.fileFaces ? ` · drawn: ${count(spec.faces)} of ${count(spec.fileFaces)} faces` : '';
    view.caption.textContent = (spec.caption || '') + drawn;
    const surface = gltf ? part(gltf, 'surface') : null;
    if (!surface) {
      view.status = gltf === undefined ? 'none' : 'failed';
      view.message.textContent = spec.message || (gltf === undefined ? 'no mesh' : 'its GLB could not be decoded');
      view.canvas.style.display = 'none';
      view.message.style.display = '';
      view.cell.dataset.status = view.status;
      return;
    }
    const mesh = new T.Mesh(surface, surfaceMaterial(isGT));
    mesh.userData.ownsGeometry = true;
    const lines = new T.MeshBasicMaterial({ color: 0x1f2937, wireframe: true, transparent: true, opacity: 0.35 });
    const wire = new T.Mesh(surface, lines);
    view.parts = { mesh, wire, colours: !!surface.getAttribute('color') };
    view.content.add(mesh, wire);
    if (gtEdges) view.content.add(view.parts.gtEdges = pointsOf(gtEdges, isGT));  // the GT view owns it
    const edges = part(gltf, 'edges');
    if (edges && !isGT) view.content.add(view.parts.edges = pointsOf(edges, true));
    view.canvas.style.display = '';
    view.message.style.display = 'none';
    view.status = 'ok';
    view.cell.dataset.status = 'ok';
  }

  function applyToggles() {
    for (const view of views) {
      const { mesh, wire, gtEdges, edges, colours } = view.parts;
      if (!mesh) continue;
      const coloured = state.error && colours;
      mesh.material.vertexColors = coloured;
      mesh.material.color.set(coloured ? 0xffffff : (view === views[0] ? data.gtColor : data.baseColor));
      mesh.material.needsUpdate = true;
      wire.visible = state.wireframe;
      if (gtEdges) gtEdges.visible = state.edges;
      if (edges) edges.visible = state.edges;
    }
    requestRender();
  }

  function resetCamera() {
    const camera = data.shapes[state.shape] && data.shapes[state.shape].camera;
    if (!camera || !views.length) return;
    const first = views[0];
    first.camera.position.fromArray(camera.position);
    first.camera.fov = camera.fov;
    first.camera.near = camera.near;
    first.camera.far = camera.far;
    first.camera.zoom = 1;
    first.controls.target.fromArray(camera.target);
    first.camera.lookAt(first.controls.target);
    first.controls.update();
    for (const view of views) view.camera.fov = camera.fov;
    follow(0);
  }

  async function select(index) {
    state.shape = index;
    state.loaded = false;
    const shape = data.shapes[index];
    for (const view of views) view.cell.dataset.status = 'loading';
    const loaded = await Promise.all(shape.views.map((spec) => spec.glb
      ? parse(spec.glb).catch((error) => { console.error(`viewer: ${shape.name} / ${spec.name}: ${error}`); return null; })
      : Promise.resolve(undefined)));
    if (state.shape !== index) return;  // another shape was picked meanwhile
    const gtEdges = loaded[0] ? part(loaded[0], 'edges') : null;
    shape.views.forEach((spec, i) => fill(views[i], spec, loaded[i], gtEdges, i === 0));
    for (const view of views) resize(view);
    resetCamera();
    applyToggles();
    renderNow();
    state.loaded = true;
  }

  const count = data.shapes.length ? data.shapes[0].views.length : 0;
  for (let i = 0; i < count; i++) views.push(makeView(i));
  for (const [name, box] of Object.entries(toggles)) {
    if (box) box.addEventListener('change', () => { state[name] = box.checked; applyToggles(); });
  }
  if (picker) picker.addEventListener('change', () => select(Number(picker.value)));
  const reset = document.getElementById('viewer-reset');
  if (reset) reset.addEventListener('click', resetCamera);
  window.addEventListener('resize', () => { for (const view of views) resize(view); requestRender(); });

  window.salsbenchViewer = {
    state,
    select,
    renderNow,
    status: () => views.map((view) => ({ name: view.title.textContent, status: view.status })),
    cameras: () => views.map((view) => ({
      position: view.camera.position.toArray(), target: view.controls.target.toArray(),
      quaternion: view.camera.quaternion.toArray(),
    })),
    image: (i) => { renderNow(); return views[i].canvas.toDataURL('image/png'); },
  };
  if (data.shapes.length) select(0);
})();
