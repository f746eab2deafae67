"""The texture look-ahead worker ends before Python finalises.

A daemon thread still inside OpenCV when the interpreter finalises is ended from within
OpenCV's C++ frames, and the process aborts ("terminate called without an active
exception", exit code 134) after its work is done: a run that wrote everything could still
end with a crash. The worker is closed and joined at exit instead.
"""

from __future__ import annotations

import subprocess
import sys
import textwrap

from helpers import REPO

CHILD = textwrap.dedent(
    """
    import atexit, math, threading

    def after_close():  # registered first, so it runs after the look-ahead's own handler
        alive = [t.name for t in threading.enumerate() if t.name == "texture-lookahead"]
        print("alive at exit:", alive, flush=True)

    atexit.register(after_close)

    from perception.synth.scene import PalletSpec, Scene
    from perception.synth.texture_lookahead import _TEXTURES

    scene = Scene.build(
        [PalletSpec(str(k), "AB"[k % 2], 9.3, -2.0 + 1.3 * k, 0.2, math.pi) for k in range(30)]
    )
    quads = [q for q in scene.objects if callable(q.texture)]
    _TEXTURES.want(quads)  # far more than can be made before the exit below
    print("queued", len(quads), flush=True)
    """
)


def test_the_worker_is_joined_before_the_interpreter_finalises():
    out = subprocess.run(
        [sys.executable, "-c", CHILD], cwd=REPO, capture_output=True, text=True, timeout=120
    )
    assert out.returncode == 0, out.stderr[-2000:]
    assert "queued" in out.stdout
    assert "alive at exit: []" in out.stdout, out.stdout


def test_a_closed_worker_takes_no_more_work():
    from perception.synth.scene import PalletSpec, Scene
    from perception.synth.texture_lookahead import _Textures

    textures = _Textures()
    scene = Scene.build([PalletSpec("1", "A", 9.3, 0.0, 0.2, 3.14159)])
    quads = [q for q in scene.objects if callable(q.texture)]
    textures.close()
    textures.want(quads)
    assert textures._thread is None and not textures._queue
    textures.ready(quads[0])  # a drawing thread still makes what it needs itself
    assert not callable(quads[0].texture)
