"""Seed labels of the label fuzzers: a small synthetic PDS3 Mastcam-style label and a PDS4
Mastcam-Z-style label, written inline with the real keywords / element names."""

PDS3_SEED = """\
PDS_VERSION_ID = PDS3
/* synthetic Mastcam-style label for fuzzing */
^IMAGE = ("FUZZ_0001.IMG")
MSL:ACTIVE_FLIGHT_STRING_ID = "B"
INSTRUMENT_ID = MAST_LEFT
PLANET_DAY_NUMBER = 2663
PRODUCT_ID = "2663ML0139550021002124C00_DRCX"
ROVER_MOTION_COUNTER_NAME = ("SITE", "DRIVE", "POSE", "ARM")
ROVER_MOTION_COUNTER = (78, 2858, 40, 312)
START_TIME = 2020-02-02T06:30:46.741
GROUP = GEOMETRIC_CAMERA_MODEL_PARMS
 MODEL_TYPE = "CAHVOR"
 MODEL_COMPONENT_1 = ( 8.197440e-01, 4.314046e-01, -1.975884e+00 )
 MODEL_COMPONENT_2 = ( 9.246611e-01, 3.557514e-01, 1.357450e-01 )
 MODEL_COMPONENT_3 = ( -1.183870e+03, 4.521644e+03, 8.306529e+01 )
 MODEL_COMPONENT_4 = ( -3.828919e+02, -1.610776e+02, 4.631332e+03 )
 MODEL_COMPONENT_5 = ( 9.242420e-01, 3.575774e-01, 1.337885e-01 )
 MODEL_COMPONENT_6 = ( -1.510000e-04, -1.391890e-01, -1.250336e+00 )
 REFERENCE_COORD_SYSTEM_NAME = ROVER_NAV_FRAME
END_GROUP = GEOMETRIC_CAMERA_MODEL_PARMS
GROUP = ROVER_COORDINATE_SYSTEM_PARMS
 MSL:SOLUTION_ID = telemetry
 COORDINATE_SYSTEM_NAME = ROVER_NAV_FRAME
 ORIGIN_OFFSET_VECTOR = (-168.132843, -44.091644, -23.868143)
 ORIGIN_ROTATION_QUATERNION = (0.1469343, 0.1967358, -0.1234583, -0.9614902)
 REFERENCE_COORD_SYSTEM_NAME = SITE_FRAME
END_GROUP = ROVER_COORDINATE_SYSTEM_PARMS
GROUP = OBSERVATION_REQUEST_PARMS
 RATIONALE_DESC = "Documentation of concretions in the
base of the pediment capping unit"
END_GROUP = OBSERVATION_REQUEST_PARMS
GROUP = IMAGE_REQUEST_PARMS
 LINES = 1200
 LINE_SAMPLES = 1344
END_GROUP = IMAGE_REQUEST_PARMS
GROUP = INSTRUMENT_STATE_PARMS
 HORIZONTAL_FOV = 14.1467
 VERTICAL_FOV = 5.3288
 EXPOSURE_DURATION = 9.4 <ms>
END_GROUP = INSTRUMENT_STATE_PARMS
GROUP = DERIVED_IMAGE_PARMS
 MSL:COVER_STATE_FLAG = "N/A"
 FIXED_INSTRUMENT_AZIMUTH = 217.9337
 FIXED_INSTRUMENT_ELEVATION = 5.3246
END_GROUP = DERIVED_IMAGE_PARMS
OBJECT = IMAGE
 LINES = 432
 LINE_SAMPLES = 1152
 SAMPLE_BIT_MASK = 2#11111111#
END_OBJECT = IMAGE
END
"""

PDS4_SEED = """\
<?xml version="1.0" encoding="UTF-8"?>
<Product_Observational xmlns="http://pds.nasa.gov/pds4/pds/v1"
    xmlns:geom="http://pds.nasa.gov/pds4/geom/v1"
    xmlns:img="http://pds.nasa.gov/pds4/img/v1"
    xmlns:img_surface="http://pds.nasa.gov/pds4/img_surface/v1"
    xmlns:mars2020="http://pds.nasa.gov/pds4/mission/mars2020/v1">
  <Identification_Area>
    <logical_identifier>urn:nasa:pds:mars2020_mastcamz_ops_calibrated:data:zlf_0052_0671559321_081rad_n0031950zcam05024_110085j</logical_identifier>
    <version_id>1.0</version_id>
    <Alias_List>
      <Alias>
        <alternate_id>ZLF_0052_0671559321_081RAD_N0031950ZCAM05024_110085J01</alternate_id>
        <comment>VICAR PRODUCT_ID</comment>
      </Alias>
    </Alias_List>
  </Identification_Area>
  <Observation_Area>
    <Time_Coordinates>
      <start_date_time>2021-04-13T04:17:42.580Z</start_date_time>
    </Time_Coordinates>
    <Mission_Area>
      <mars2020:Mars2020_Parameters>
        <mars2020:Observation_Information>
          <mars2020:sol_number>52</mars2020:sol_number>
        </mars2020:Observation_Information>
      </mars2020:Mars2020_Parameters>
    </Mission_Area>
    <Discipline_Area>
      <geom:Geometry>
        <geom:Geometry_Lander>
          <geom:Camera_Model_Parameters>
            <geom:model_type>CAHVOR</geom:model_type>
            <geom:CAHVOR_Model>
              <geom:Vector_Center>
                <geom:x_position unit="m">0.92755</geom:x_position>
                <geom:y_position unit="m">0.589019</geom:y_position>
                <geom:z_position unit="m">-1.98371</geom:z_position>
              </geom:Vector_Center>
              <geom:Vector_Axis>
                <geom:x_unit>-0.0735652</geom:x_unit>
                <geom:y_unit>0.995441</geom:y_unit>
                <geom:z_unit>0.0608455</geom:z_unit>
              </geom:Vector_Axis>
              <geom:Vector_Horizontal>
                <geom:x_pixel>-14929.1</geom:x_pixel>
                <geom:y_pixel>-340.04</geom:y_pixel>
                <geom:z_pixel>-70.4085</geom:z_pixel>
              </geom:Vector_Horizontal>
              <geom:Vector_Vertical>
                <geom:x_pixel>-116.303</geom:x_pixel>
                <geom:y_pixel>-182.888</geom:y_pixel>
                <geom:z_pixel>14929.3</geom:z_pixel>
              </geom:Vector_Vertical>
              <geom:Vector_Optical>
                <geom:x_unit>-0.079209</geom:x_unit>
                <geom:y_unit>0.995883</geom:y_unit>
                <geom:z_unit>0.0442549</geom:z_unit>
              </geom:Vector_Optical>
              <geom:Radial_Terms>
                <geom:c0>0.000232333</geom:c0>
                <geom:c1>0.449144</geom:c1>
                <geom:c2>0.08829</geom:c2>
              </geom:Radial_Terms>
            </geom:CAHVOR_Model>
            <geom:Coordinate_Space_Reference>
              <geom:Coordinate_Space_Indexed>
                <geom:coordinate_space_frame_type>ROVER_NAV_FRAME</geom:coordinate_space_frame_type>
                <geom:Coordinate_Space_Index>
                  <geom:index_id>SITE</geom:index_id>
                  <geom:index_value_number>3</geom:index_value_number>
                </geom:Coordinate_Space_Index>
                <geom:Coordinate_Space_Index>
                  <geom:index_id>DRIVE</geom:index_id>
                  <geom:index_value_number>1950</geom:index_value_number>
                </geom:Coordinate_Space_Index>
              </geom:Coordinate_Space_Indexed>
            </geom:Coordinate_Space_Reference>
          </geom:Camera_Model_Parameters>
          <geom:Coordinate_Space_Definition>
            <local_identifier>ROVER_NAV_FRAME_3_1950_4_0_0_0_232_306_0_0</local_identifier>
            <geom:Coordinate_Space_Present>
              <geom:Coordinate_Space_Indexed>
                <geom:coordinate_space_frame_type>ROVER_NAV_FRAME</geom:coordinate_space_frame_type>
                <geom:Coordinate_Space_Index>
                  <geom:index_id>SITE</geom:index_id>
                  <geom:index_value_number>3</geom:index_value_number>
                </geom:Coordinate_Space_Index>
              </geom:Coordinate_Space_Indexed>
            </geom:Coordinate_Space_Present>
            <geom:Vector_Origin_Offset>
              <geom:x_position unit="m">10.3131</geom:x_position>
              <geom:y_position unit="m">65.9943</geom:y_position>
              <geom:z_position unit="m">0.715083</geom:z_position>
            </geom:Vector_Origin_Offset>
            <geom:Quaternion_Plus_Direction>
              <geom:qcos>0.00131628</geom:qcos>
              <geom:qsin1>0.000646026</geom:qsin1>
              <geom:qsin2>-0.000920782</geom:qsin2>
              <geom:qsin3>0.999999</geom:qsin3>
            </geom:Quaternion_Plus_Direction>
            <geom:Coordinate_Space_Reference>
              <geom:Coordinate_Space_Indexed>
                <geom:coordinate_space_frame_type>SITE_FRAME</geom:coordinate_space_frame_type>
              </geom:Coordinate_Space_Indexed>
            </geom:Coordinate_Space_Reference>
          </geom:Coordinate_Space_Definition>
          <geom:Coordinate_Space_Definition>
            <local_identifier>RSM_HEAD_FRAME_3_1950_4_0_0_0_232_306_0_0</local_identifier>
            <geom:Coordinate_Space_Present>
              <geom:Coordinate_Space_Indexed>
                <geom:coordinate_space_frame_type>RSM_HEAD_FRAME</geom:coordinate_space_frame_type>
              </geom:Coordinate_Space_Indexed>
            </geom:Coordinate_Space_Present>
            <geom:Vector_Origin_Offset>
              <geom:x_position unit="m">0.804961</geom:x_position>
              <geom:y_position unit="m">0.559512</geom:y_position>
              <geom:z_position unit="m">-1.91903</geom:z_position>
            </geom:Vector_Origin_Offset>
            <geom:Quaternion_Plus_Direction>
              <geom:qcos>0.685182</geom:qcos>
              <geom:qsin1>0.0155495</geom:qsin1>
              <geom:qsin2>-0.0160294</geom:qsin2>
              <geom:qsin3>0.72803</geom:qsin3>
            </geom:Quaternion_Plus_Direction>
            <geom:Coordinate_Space_Reference>
              <Local_Internal_Reference>
                <local_identifier_reference>ROVER_NAV_FRAME_3_1950_4_0_0_0_232_306_0_0</local_identifier_reference>
              </Local_Internal_Reference>
            </geom:Coordinate_Space_Reference>
          </geom:Coordinate_Space_Definition>
          <geom:Derived_Geometry>
            <geom:instrument_azimuth unit="deg">94.4856</geom:instrument_azimuth>
            <geom:instrument_elevation unit="deg">-2.968</geom:instrument_elevation>
            <geom:Coordinate_Space_Reference>
              <Local_Internal_Reference>
                <local_identifier_reference>ROVER_NAV_FRAME_3_1950_4_0_0_0_232_306_0_0</local_identifier_reference>
              </Local_Internal_Reference>
            </geom:Coordinate_Space_Reference>
          </geom:Derived_Geometry>
          <geom:Derived_Geometry>
            <geom:instrument_azimuth unit="deg">274.338</geom:instrument_azimuth>
            <geom:instrument_elevation unit="deg">-2.8571</geom:instrument_elevation>
            <geom:Coordinate_Space_Reference>
              <geom:Coordinate_Space_Indexed>
                <geom:coordinate_space_frame_type>SITE_FRAME</geom:coordinate_space_frame_type>
              </geom:Coordinate_Space_Indexed>
            </geom:Coordinate_Space_Reference>
          </geom:Derived_Geometry>
          <geom:Motion_Counter>
            <geom:Motion_Counter_Index>
              <geom:index_id>SITE</geom:index_id>
              <geom:index_value_number>3</geom:index_value_number>
            </geom:Motion_Counter_Index>
            <geom:Motion_Counter_Index>
              <geom:index_id>DRIVE</geom:index_id>
              <geom:index_value_number>1950</geom:index_value_number>
            </geom:Motion_Counter_Index>
            <geom:Motion_Counter_Index>
              <geom:index_id>POSE</geom:index_id>
              <geom:index_value_number>4</geom:index_value_number>
            </geom:Motion_Counter_Index>
          </geom:Motion_Counter>
        </geom:Geometry_Lander>
      </geom:Geometry>
      <img:Imaging>
        <img:Subframe>
          <img:line_fov unit="deg">4.63392</img:line_fov>
          <img:sample_fov unit="deg">6.35693</img:sample_fov>
        </img:Subframe>
      </img:Imaging>
      <img_surface:Surface_Imaging>
        <img_surface:Instrument_Information>
          <img_surface:ops_instrument_key>MCZ_LEFT</img_surface:ops_instrument_key>
        </img_surface:Instrument_Information>
      </img_surface:Surface_Imaging>
    </Discipline_Area>
  </Observation_Area>
  <File_Area_Observational>
    <File>
      <file_name>ZLF_0052_0671559321_081RAD_N0031950ZCAM05024_110085J01.IMG</file_name>
    </File>
    <Array_3D_Image>
      <Axis_Array>
        <axis_name>Band</axis_name>
        <elements>3</elements>
      </Axis_Array>
      <Axis_Array>
        <axis_name>Line</axis_name>
        <elements>1200</elements>
      </Axis_Array>
      <Axis_Array>
        <axis_name>Sample</axis_name>
        <elements>1648</elements>
      </Axis_Array>
    </Array_3D_Image>
  </File_Area_Observational>
</Product_Observational>
"""
