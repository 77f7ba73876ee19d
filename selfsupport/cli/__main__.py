"""``python -m selfsupport.cli``: the same as ``python -m selfsupport`` (:mod:`selfsupport.__main__`)."""
import runpy

runpy.run_module("selfsupport", run_name="__main__", alter_sys=True)
