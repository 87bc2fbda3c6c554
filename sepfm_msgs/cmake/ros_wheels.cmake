# Building against ROS 2 Jazzy from its PyPI wheels (ros-jazzy-*). Those wheels install a ROS
# prefix into the Python environment itself (<prefix>/share/<pkg>/cmake, <prefix>/lib,
# <prefix>/include). On a ROS machine with a sourced install neither function changes anything.

# Without AMENT_PREFIX_PATH (a plain virtual environment, or pip's isolated build environment),
# names the prefixes of the interpreter's site-packages folders that hold an ament index, for
# this configure run only (rosidl looks its type supports up in the ament index), and adds them
# to CMAKE_PREFIX_PATH. Needs Python3_EXECUTABLE.
function(sepfm_msgs_use_ros_wheel_prefixes)
  if(NOT "$ENV{AMENT_PREFIX_PATH}" STREQUAL "")
    return()
  endif()
  set(code [=[
import sys
from pathlib import Path
prefixes = []
for entry in sys.path:
    path = Path(entry)
    if path.name in ("site-packages", "dist-packages") and len(path.parents) > 2:
        prefix = path.parents[2]  # <prefix>/lib/pythonX.Y/site-packages
        if (prefix / "share" / "ament_index").is_dir() and str(prefix) not in prefixes:
            prefixes.append(str(prefix))
print(";".join(prefixes), end="")
]=])
  execute_process(
    COMMAND "${Python3_EXECUTABLE}" -c "${code}"
    OUTPUT_VARIABLE prefixes
    RESULT_VARIABLE result
  )
  if(NOT result EQUAL 0 OR prefixes STREQUAL "")
    message(FATAL_ERROR
      "AMENT_PREFIX_PATH is not set and ${Python3_EXECUTABLE} has no ROS 2 wheels installed: "
      "source a ROS 2 Jazzy install, or build with pip (pyproject.toml names the wheels)")
  endif()
  message(STATUS "ROS 2 wheel prefixes (AMENT_PREFIX_PATH for this configure run): ${prefixes}")
  string(REPLACE ";" ":" joined "${prefixes}")
  set(ENV{AMENT_PREFIX_PATH} "${joined}")
  set(CMAKE_PREFIX_PATH ${prefixes} ${CMAKE_PREFIX_PATH} PARENT_SCOPE)
endfunction()

# The wheels' exported <pkg>__rosidl_generator_py targets name the Python and NumPy include
# folders of the machine that built the wheels (e.g. /opt/python/cp311-cp311/include/python3.11),
# and CMake refuses imported targets whose include folders do not exist. Replaces the missing
# folders of every such target of this directory by this interpreter's (Python3_INCLUDE_DIRS,
# Python3_NumPy_INCLUDE_DIRS). Call after rosidl_generate_interfaces().
function(sepfm_msgs_fix_python_include_dirs)
  get_directory_property(imported IMPORTED_TARGETS)
  set(fixed "")
  foreach(target IN LISTS imported)
    if(NOT target MATCHES "__rosidl_generator_py$")
      continue()
    endif()
    get_target_property(dirs ${target} INTERFACE_INCLUDE_DIRECTORIES)
    if(NOT dirs)
      continue()
    endif()
    set(kept "")
    set(missing FALSE)
    foreach(dir IN LISTS dirs)
      if(EXISTS "${dir}")
        list(APPEND kept "${dir}")
      else()
        set(missing TRUE)
      endif()
    endforeach()
    if(missing)
      list(APPEND kept ${Python3_INCLUDE_DIRS} ${Python3_NumPy_INCLUDE_DIRS})
      list(REMOVE_DUPLICATES kept)
      set_target_properties(${target} PROPERTIES INTERFACE_INCLUDE_DIRECTORIES "${kept}")
      list(APPEND fixed ${target})
    endif()
  endforeach()
  if(fixed)
    message(STATUS "Python include folders of the build machine replaced by this one's in: ${fixed}")
  endif()
endfunction()
