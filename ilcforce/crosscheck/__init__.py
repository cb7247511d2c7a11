"""The contact model cross-checked (docs/crosscheck.md): ilcforce's controllers on its task with MuJoCo as the
true plant and MuJoCo's own soft contact as the wall. A cross-check, never the default plant."""
