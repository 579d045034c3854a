"""The shared model both sides use: vehicle constants, the one NED/FRD <-> model-frame conversion, cable
geometry, flat outputs, measurement records and the controller's input record.
"""
