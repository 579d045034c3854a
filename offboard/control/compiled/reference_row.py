"""The reference row the compiled laws read (``REF_SIZE`` floats): ``offboard.control.reference.FlatSample``
flattened, orders 0..6 of ``F_x``, ``F_y`` (m), ``z`` (m) and ``psi`` (rad)."""

REF_FX = 0  # orders 0..6 (7 floats)
REF_FY = 7
REF_Z = 14
REF_PSI = 21
REF_SIZE = 28
