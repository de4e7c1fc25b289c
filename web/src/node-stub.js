// draco3d's glue names Node's fs and path on a branch taken only under Node.js.
export default {};
