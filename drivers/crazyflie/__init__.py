"""Real hardware: :mod:`.cflib_link` (the radio link through cflib), :mod:`.cf_platform` (the
platform, built from injected parts), :mod:`.mocap` (motioncapture), :mod:`.cpx` (the CPX
wire format) and :mod:`.aideck_stream` (the AI-deck image stream). Never imports the
simulator: software in the loop is a ``udp://`` URI (see ``drivers.rig.factory``)."""
