// The entry of the viewer's JavaScript bundle (scripts/vendor_three.sh bundles it into
// three.bundle.min.js, a classic script that defines the global THREE): three.js itself and the
// three add-ons reports/viewer.js uses.
export * from 'three';
export { OrbitControls } from 'three/examples/jsm/controls/OrbitControls.js';
export { GLTFLoader } from 'three/examples/jsm/loaders/GLTFLoader.js';
export { DRACOLoader } from 'three/examples/jsm/loaders/DRACOLoader.js';
