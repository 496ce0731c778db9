"""The spray deposition's packed arrays, each declared once as a :class:`numkit.Layout`: the
input row, the parameter header, the state row, a nozzle's window moments, a wide part's
moments, the splat's scratch rows and one droplet class's footprint; the kernels
(:mod:`ag_uav.world.deposition_kernels`) index them by these names."""

from __future__ import annotations

from numkit import Layout

#: one input row: position, velocity, R (row-major body → world), total thrust, wind, nozzle
#: command
INPUT = Layout("pos:3 vel:3 r:9 thrust wind:3 cmd")
INPUT_WIDTH = INPUT.size

#: header slots of the parameter vector (float64); arrays follow at the offsets stored in it
#: (the ``o_*`` slots); span, vtx, wingv: the forward-flight wake's vortex pair; o_thr: each
#: class's release variance from a rotary atomiser's throw (r_t² / 2; zeros for nozzles)
DEP_PARAMS = Layout("rate swath vmin don doff offnow tau rhoa area s0 rotz iw delta siga sig0 "
                    "x0 y0 cell nx ny nlev flushd flusht m k merge o_noz o_share o_vt o_taup "
                    "o_frac o_lev nozc qmin esc ell z0 tmax o_tt o_h o_r edge sm bd0 rj st50 "
                    "invl wj hi span vtx wingv o_thr")
_P = DEP_PARAMS.at
P_RATE, P_SWATH, P_VMIN, P_DON, P_DOFF = _P.RATE, _P.SWATH, _P.VMIN, _P.DON, _P.DOFF
P_OFFNOW, P_TAU, P_RHOA, P_AREA, P_S0 = _P.OFFNOW, _P.TAU, _P.RHOA, _P.AREA, _P.S0
P_ROTZ, P_IW, P_DELTA, P_SIGA, P_SIG0 = _P.ROTZ, _P.IW, _P.DELTA, _P.SIGA, _P.SIG0
P_X0, P_Y0, P_CELL, P_NX, P_NY, P_NLEV = _P.X0, _P.Y0, _P.CELL, _P.NX, _P.NY, _P.NLEV
P_FLUSHD, P_FLUSHT, P_M, P_K, P_MERGE = _P.FLUSHD, _P.FLUSHT, _P.M, _P.K, _P.MERGE
P_O_NOZ, P_O_SHARE, P_O_VT, P_O_TAUP = _P.O_NOZ, _P.O_SHARE, _P.O_VT, _P.O_TAUP
P_O_FRAC, P_O_LEV, P_NOZC, P_QMIN, P_ESC = _P.O_FRAC, _P.O_LEV, _P.NOZC, _P.QMIN, _P.ESC
P_ELL, P_Z0, P_TMAX, P_O_TT, P_O_H, P_O_R = _P.ELL, _P.Z0, _P.TMAX, _P.O_TT, _P.O_H, _P.O_R
P_EDGE, P_SM, P_BD0, P_RJ, P_ST50 = _P.EDGE, _P.SM, _P.BD0, _P.RJ, _P.ST50
P_INVL, P_WJ, P_HI, P_SPAN, P_VTX, P_WINGV = _P.INVL, _P.WJ, _P.HI, _P.SPAN, _P.VTX, _P.WINGV
P_O_THR = _P.O_THR
P_HEADER = DEP_PARAMS.size
#: state slots per row; the window's accumulators follow at S_ACC: the litres, the
#: litre-weighted sum of the input row (INPUT_WIDTH), then per nozzle its :data:`MOMENTS`
DEP_STATE = Layout("on inc q travel ticks inside lx ly sprayed ingrid outside drift pending "
                   "litres_tick air evap")
_S = DEP_STATE.at
S_ON, S_INC, S_Q, S_TRAVEL, S_TICKS = _S.ON, _S.INC, _S.Q, _S.TRAVEL, _S.TICKS
S_INSIDE, S_LX, S_LY, S_SPRAYED, S_INGRID = _S.INSIDE, _S.LX, _S.LY, _S.SPRAYED, _S.INGRID
S_OUTSIDE, S_DRIFT, S_PENDING, S_LITRES_TICK = _S.OUTSIDE, _S.DRIFT, _S.PENDING, _S.LITRES_TICK
S_AIR, S_EVAP = _S.AIR, _S.EVAP
S_ACC = DEP_STATE.size
#: a nozzle's release moments over the window: V, Σx, Σy, Σx², Σy² (litre-weighted)
MOMENTS = Layout("v sx sy sxx syy")
NACC = MOMENTS.size
#: per (class, wake/escaped) a wide part's gathered moments: V, Sx, Sy, Sxx, Syy, V·σx², V·σy²
WIDE = Layout("v sx sy sxx syy vkx vky")
NSLOW = WIDE.size
#: the rows of the splat's scratch: the x and y cell weights, the window's mean input row
SCRATCH = Layout("wx wy row")

#: one droplet class's footprint (the kernels' class footprint)
FOOTPRINT = Layout("wake wx wy wvar wland esc ex ey evx evy mut lamt pair rland rair ux uy "
                   "vort vx vy vvx vvy vland")
_F = FOOTPRINT.at
F_WAKE, F_WX, F_WY, F_WVAR, F_WLAND, F_ESC = _F.WAKE, _F.WX, _F.WY, _F.WVAR, _F.WLAND, _F.ESC
F_EX, F_EY, F_EVX, F_EVY, F_MUT, F_LAMT = _F.EX, _F.EY, _F.EVX, _F.EVY, _F.MUT, _F.LAMT
F_PAIR, F_RLAND, F_RAIR, F_UX, F_UY = _F.PAIR, _F.RLAND, _F.RAIR, _F.UX, _F.UY
F_VORT, F_VX, F_VY, F_VVX, F_VVY, F_VLAND = _F.VORT, _F.VX, _F.VY, _F.VVX, _F.VVY, _F.VLAND
NFOOT = FOOTPRINT.size
#: the parts of a class that land apart: the wake (the jet and its outwash), the escaped, and the
#: forward-flight wake's trailing vortex pair (an option, share 0 when off)
NPART = 3
