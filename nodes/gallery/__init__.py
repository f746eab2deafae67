"""Gallery tools outside a flight: the ``btrun gallery`` command and the demo gallery.

* :mod:`nodes.gallery.cli` - ``btrun gallery list|enrol|remove|export|evaluate|demo``;
* :mod:`nodes.gallery.demo` - enrolment scans rendered without a flight, and the demo
  gallery (every pallet side of the world) built from them on first use.
"""
