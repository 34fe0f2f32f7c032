import sys, os
sys.path.insert(0, "/tmp/diag")
from mjx_envs.physics import backends
backends.import_mjx()
if os.environ.get("UNIQ", "1") == "1":
    import uniq; uniq.install()
from daddpg_jax.cli import evaluate
sys.exit(evaluate.main(sys.argv[1:]))
